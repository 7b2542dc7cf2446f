//! Moving one network's parameters towards another's: DQN's soft target update and the
//! segmenter's exponential moving average of weights are both `blend`.

use std::collections::HashMap;

use burn::module::{Module, ModuleMapper, ModuleVisitor, Param, ParamId};
use burn::tensor::Tensor;

/// `target ← τ·source + (1 − τ)·target`, parameter by parameter, matched by id (so `target`
/// must have started as a copy of `source`). Every float tensor the modules hold takes
/// part, batch-norm running statistics included; a parameter `source` lacks stays as it is.
pub fn blend<M: Module>(target: M, source: &M, tau: f64) -> M {
    struct Collect(HashMap<ParamId, Tensor<1>>);
    impl ModuleVisitor for Collect {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.0.insert(param.id, param.val().flatten::<1>(0, D - 1));
        }
    }
    struct Blend {
        source: HashMap<ParamId, Tensor<1>>,
        tau: f64,
    }
    impl ModuleMapper for Blend {
        fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
            let Some(source) = self.source.remove(&param.id) else {
                return param;
            };
            let tau = self.tau;
            param.map(|t| {
                let shape = t.shape();
                t.mul_scalar(1.0 - tau) + source.reshape(shape).mul_scalar(tau)
            })
        }
    }
    let mut collect = Collect(HashMap::new());
    source.visit(&mut collect);
    target.map(&mut Blend {
        source: collect.0,
        tau,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::{Linear, LinearConfig};
    use burn::tensor::{Device, TensorData};

    /// The layer with every float replaced by `value` (ids kept, as a copy being trained).
    fn filled(layer: &Linear, value: f32) -> Linear {
        struct Fill(f32);
        impl ModuleMapper for Fill {
            fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
                let v = self.0;
                param.map(|t| t.zeros_like().add_scalar(v))
            }
        }
        layer.clone().map(&mut Fill(value))
    }

    #[test]
    fn blend_moves_each_parameter_the_given_share_of_the_way() {
        let device = Device::flex();
        let layer = LinearConfig::new(3, 2).init(&device);
        let target = filled(&layer, 1.0);
        let source = filled(&layer, 5.0);
        let moved = blend(target, &source, 0.25);
        // 0.75 · 1 + 0.25 · 5 = 2, for the weight and the bias alike.
        let weight: Vec<f32> = moved
            .weight
            .val()
            .into_data()
            .try_to_vec::<f32>()
            .unwrap_or_default();
        assert_eq!(weight, vec![2.0; 6]);
        let bias = moved.bias.map(|b| b.val().into_data());
        assert_eq!(bias, Some(TensorData::from([2.0f32, 2.0])));
        // A module whose ids the source does not share is left as it was.
        let stranger = filled(&LinearConfig::new(3, 2).init(&device), 5.0);
        let kept = blend(filled(&layer, 1.0), &stranger, 0.25);
        let weight: Vec<f32> = kept
            .weight
            .val()
            .into_data()
            .try_to_vec::<f32>()
            .unwrap_or_default();
        assert_eq!(weight, vec![1.0; 6]);
    }
}
