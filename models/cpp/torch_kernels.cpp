// LibTorch code the Rust side cannot reach through tch, for the `libtorch` feature: the
// autograd engine started from a given output gradient (models::layers), and the segmenter's
// merged cross-entropy and Dice loss with its gradient in two passes over the logits
// (models::segmenter::loss). Called through models/src/torch_kernels.rs.
//
// Every function returns 0, or 1 with the exception's message in `error` (at most
// `error_len` bytes with the terminating zero) and nothing written to its outputs. Output
// tensors are new `at::Tensor`s owned by the caller (tch's `at_free` deletes them).

#include <ATen/ATen.h>
#include <ATen/Parallel.h>
#include <torch/csrc/autograd/autograd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <exception>
#include <vector>

namespace {

int report(const std::exception &e, char *error, size_t error_len) {
  if (error_len > 0) {
    size_t len = std::min(std::strlen(e.what()), error_len - 1);
    std::memcpy(error, e.what(), len);
    error[len] = '\0';
  }
  return 1;
}

}  // namespace

// The gradients of `output` with respect to `inputs[0..n]` (leaves of its graph) for the
// output gradient `grad` (same shape and type as `output`): `torch::autograd::grad`. tch
// starts the engine only from a scalar with a gradient of one, so without this a layer would
// differentiate `dot(output, grad)`, a pass reading both and another writing `grad * 1`.
extern "C" int pipeline_autograd_grad(const at::Tensor *output, const at::Tensor *grad,
                                      const at::Tensor *const *inputs, int n,
                                      at::Tensor **results, char *error, size_t error_len) {
  try {
    torch::autograd::variable_list leaves;
    leaves.reserve(n);
    for (int i = 0; i < n; ++i) leaves.push_back(*inputs[i]);
    auto grads = torch::autograd::grad({*output}, leaves, {*grad}, /*retain_graph=*/false,
                                       /*create_graph=*/false, /*allow_unused=*/false);
    for (int i = 0; i < n; ++i) results[i] = new at::Tensor(std::move(grads[i]));
    return 0;
  } catch (const std::exception &e) {
    return report(e, error, error_len);
  }
}

// `CE + dice_weight · Dice` of models/src/segmenter/loss.rs (its module docs give the
// definitions) and its gradient with respect to the logits, from the tensors of a
// `LossTargets`:
//
//   logits  [B, C, H, W]  allowed [B, C, H, W]  weights [B, H, W]  single [B, 1, H, W]
//   present [C]
//
// With p = softmax(logits) and a = allowed, per pixel k = Σ_c a_c p_c (the probability of an
// acceptable class):
//   CE   = Σ_px w · −ln max(k, 1e-30) / weight_sum                    (0 if weight_sum = 0)
//   Dice = Σ_c present_c (1 − 2 I_c / max(P_c + T_c, 1e-7)) / max(Σ present, 1)
//          with I_c = Σ s p_c a_c, P_c = Σ s p_c, T_c = Σ s a_c over the pixels (s = single).
// Gradient with respect to the logits, through the softmax:
//   ∂/∂z_c = p_c [ w' (1 − a_c / k) + s (d_c − Σ_j d_j p_j) ],   w' = w / weight_sum,
//   d_c = ∂(dice_weight · Dice)/∂p_c = −dice_weight · present_c (2 a_c / D_c − 2 I_c / D_c²) / n.
// (The clamp: below 1e-30, k carries no gradient, as burn's clamp_min.)
//
// The softmax is LibTorch's; the two passes over the pixels run in fixed blocks whose loops
// over a block's pixels vectorise, and whose partial sums are added in block order, so the
// result does not depend on the number of threads.
extern "C" int pipeline_segmentation_loss(const at::Tensor *logits_in, const at::Tensor *allowed_in,
                                          const at::Tensor *weights_in, const at::Tensor *single_in,
                                          const at::Tensor *present_in, double weight_sum,
                                          double dice_weight, at::Tensor **loss_out,
                                          at::Tensor **grad_out, char *error, size_t error_len) {
  try {
    TORCH_CHECK(logits_in->dim() == 4, "logits must be [B, C, H, W]");
    auto probabilities = at::softmax(logits_in->to(at::kFloat), 1).contiguous();
    auto allowed = allowed_in->to(at::kFloat).contiguous();
    auto weights = weights_in->to(at::kFloat).contiguous();
    auto single = single_in->to(at::kFloat).contiguous();
    auto present = present_in->to(at::kFloat).contiguous();
    const int64_t batch = probabilities.size(0), classes = probabilities.size(1);
    const int64_t plane = probabilities.size(2) * probabilities.size(3);
    TORCH_CHECK(allowed.sizes() == probabilities.sizes(), "allowed must have the logits' shape");
    TORCH_CHECK(weights.numel() == batch * plane, "weights must be [B, H, W]");
    TORCH_CHECK(single.numel() == batch * plane, "single must be [B, 1, H, W]");
    TORCH_CHECK(present.numel() == classes, "present must be [C]");

    const float *p = probabilities.data_ptr<float>();
    const float *a = allowed.data_ptr<float>();
    const float *w = weights.data_ptr<float>();
    const float *s = single.data_ptr<float>();
    const float *pr = present.data_ptr<float>();
    const bool dice = dice_weight != 0.0;

    constexpr int64_t block = 2048;
    const int64_t blocks_per_image = (plane + block - 1) / block;
    const int64_t blocks = batch * blocks_per_image;
    // A block's pixels: image b, [i0, i1) of its plane.
    auto span = [&](int64_t k, int64_t &b, int64_t &i0, int64_t &n) {
      b = k / blocks_per_image;
      i0 = (k % blocks_per_image) * block;
      n = std::min(plane, i0 + block) - i0;
    };
    // k per pixel, kept between the passes.
    std::vector<float> kept(batch * plane);

    // Pass 1: per block, Σ w·CE and the Dice sums I_c, P_c, T_c.
    const int64_t stride = 1 + 3 * classes;
    std::vector<double> partial(blocks * stride, 0.0);
    at::parallel_for(0, blocks, 1, [&](int64_t begin, int64_t end) {
      for (int64_t k = begin; k < end; ++k) {
        int64_t b, i0, n;
        span(k, b, i0, n);
        float *kp = kept.data() + b * plane + i0;
        const float *wp = w + b * plane + i0, *sp = s + b * plane + i0;
        std::fill(kp, kp + n, 0.f);
        double *out = &partial[k * stride];
        for (int64_t c = 0; c < classes; ++c) {
          const float *pc = p + (b * classes + c) * plane + i0;
          const float *ac = a + (b * classes + c) * plane + i0;
          float inter = 0.f, prob = 0.f, truth = 0.f;
          for (int64_t i = 0; i < n; ++i) {
            kp[i] += ac[i] * pc[i];
            inter += sp[i] * pc[i] * ac[i];
            prob += sp[i] * pc[i];
            truth += sp[i] * ac[i];
          }
          out[1 + c] = inter;
          out[1 + classes + c] = prob;
          out[1 + 2 * classes + c] = truth;
        }
        double ce = 0.0;
        for (int64_t i = 0; i < n; ++i)
          if (wp[i] != 0.f) ce -= wp[i] * std::log(std::max(kp[i], 1e-30f));
        out[0] = ce;
      }
    });
    std::vector<double> total(stride, 0.0);
    for (int64_t k = 0; k < blocks; ++k)
      for (int64_t j = 0; j < stride; ++j) total[j] += partial[k * stride + j];

    const double ce_scale = weight_sum > 0.0 ? 1.0 / weight_sum : 0.0;
    double count = 0.0;
    for (int64_t c = 0; c < classes; ++c) count += pr[c];
    count = std::max(count, 1.0);
    double loss = total[0] * ce_scale;
    // Per class, d_c = a_c · slope[c] + offset[c].
    std::vector<float> slope(classes, 0.f), offset(classes, 0.f);
    if (dice) {
      double dice_sum = 0.0;
      for (int64_t c = 0; c < classes; ++c) {
        const double inter = total[1 + c], d = total[1 + classes + c] + total[1 + 2 * classes + c];
        dice_sum += pr[c] * (1.0 - 2.0 * inter / std::max(d, 1e-7));
        if (pr[c] != 0.f && d > 1e-7) {
          const double scale = -dice_weight * pr[c] / count;
          slope[c] = static_cast<float>(scale * 2.0 / d);
          offset[c] = static_cast<float>(-scale * 2.0 * inter / (d * d));
        }
      }
      loss += dice_weight * dice_sum / count;
    }

    // Pass 2: the gradient.
    auto grad = at::empty(probabilities.sizes(), probabilities.options());
    float *g = grad.data_ptr<float>();
    const float ce = static_cast<float>(ce_scale);
    at::parallel_for(0, blocks, 1, [&](int64_t begin, int64_t end) {
      std::vector<float> scale(block), inv_kept(block), dot(block);
      for (int64_t k = begin; k < end; ++k) {
        int64_t b, i0, n;
        span(k, b, i0, n);
        const float *kp = kept.data() + b * plane + i0;
        const float *wp = w + b * plane + i0, *sp = s + b * plane + i0;
        for (int64_t i = 0; i < n; ++i) {
          scale[i] = wp[i] * ce;
          inv_kept[i] = kp[i] > 1e-30f ? 1.f / kp[i] : 0.f;
          dot[i] = 0.f;
        }
        if (dice) {
          for (int64_t c = 0; c < classes; ++c) {
            const float *pc = p + (b * classes + c) * plane + i0;
            const float *ac = a + (b * classes + c) * plane + i0;
            for (int64_t i = 0; i < n; ++i) dot[i] += (ac[i] * slope[c] + offset[c]) * pc[i];
          }
        }
        for (int64_t c = 0; c < classes; ++c) {
          const float *pc = p + (b * classes + c) * plane + i0;
          const float *ac = a + (b * classes + c) * plane + i0;
          float *gc = g + (b * classes + c) * plane + i0;
          for (int64_t i = 0; i < n; ++i) {
            const float ce_part = scale[i] * (1.f - ac[i] * inv_kept[i]);
            const float dice_part = sp[i] * (ac[i] * slope[c] + offset[c] - dot[i]);
            gc[i] = pc[i] * (ce_part + dice_part);
          }
        }
      }
    });
    *loss_out = new at::Tensor(at::full({1}, loss, probabilities.options()));
    *grad_out = new at::Tensor(std::move(grad));
    return 0;
  } catch (const std::exception &e) {
    return report(e, error, error_len);
  }
}
