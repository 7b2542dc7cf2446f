//! The burn segmenter computes what the same network computes in
//! PyTorch. `scripts/segmenter_reference.py` stored two small networks' weights, a fixed
//! input and PyTorch's output under `tests/data/`; here the weights are loaded into the burn
//! model and its output must match within 1e-4 (absolute), element by element.

use std::path::{Path, PathBuf};

use burn::tensor::{Device, Tensor, TensorData};
use models::segmenter::PspNetConfig;
use models::segmenter::files::{config_from_value, export_safetensors, import_safetensors};
use safetensors::SafeTensors;

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data")
}

/// A float tensor of the io file, as (values, shape).
fn read_tensor(file: &SafeTensors<'_>, name: &str) -> (Vec<f32>, Vec<usize>) {
    let view = file.tensor(name).unwrap_or_else(|e| panic!("{name}: {e}"));
    let values = view
        .data()
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    (values, view.shape().to_vec())
}

fn configs() -> serde_json::Map<String, serde_json::Value> {
    let text = std::fs::read_to_string(data_dir().join("segmenter_reference.json"))
        .unwrap_or_else(|e| panic!("segmenter_reference.json: {e}"));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("segmenter_reference.json: {e}"))
}

fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

#[test]
fn segmenter_reference_outputs_match_pytorch() {
    let device = Device::flex();
    let io_bytes = std::fs::read(data_dir().join("segmenter_reference_io.safetensors"))
        .unwrap_or_else(|e| panic!("segmenter_reference_io.safetensors: {e}"));
    let io = SafeTensors::deserialize(&io_bytes).unwrap_or_else(|e| panic!("io file: {e}"));
    let configs = configs();
    assert_eq!(configs.len(), 2);
    for (name, config) in &configs {
        // Written before `fine_skip_channels` existed: it loads with the default (off), as
        // users' older model.json files do.
        assert!(config.get("fine_skip_channels").is_none());
        let config: PspNetConfig = config_from_value(config.clone(), &PspNetConfig::new())
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(config.fine_skip_channels, 0);
        let weights = data_dir().join(format!("segmenter_reference_{name}.safetensors"));
        let model = config
            .init(&device)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        let model = import_safetensors(&weights, model).unwrap_or_else(|e| panic!("{e}"));

        let (input, shape) = read_tensor(&io, &format!("{name}.input"));
        let (expected, out_shape) = read_tensor(&io, &format!("{name}.output"));
        let shape: [usize; 4] = shape.try_into().unwrap_or_else(|_| panic!("input rank"));
        let x = Tensor::<4>::from_data(TensorData::new(input, shape), &device);
        let y = model.forward(x);
        assert_eq!(y.dims().to_vec(), out_shape, "{name}");
        let got = y.into_data().try_to_vec::<f32>().unwrap_or_default();
        let diff = max_abs_diff(&got, &expected);
        assert!(diff < 1e-4, "{name}: max |burn - pytorch| = {diff}");
        // The outputs are not trivially small: the comparison means something.
        let spread = expected.iter().map(|v| v.abs()).fold(0.0, f32::max);
        assert!(spread > 1.0, "{name}: {spread}");

        // The safetensors export round-trips to the same network.
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let exported = dir.path().join("model.safetensors");
        export_safetensors(&exported, &model).unwrap_or_else(|e| panic!("{e}"));
        let again = import_safetensors(
            &exported,
            config
                .init_seeded(&device, 9)
                .unwrap_or_else(|e| panic!("{e}")),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        let (input, _) = read_tensor(&io, &format!("{name}.input"));
        let y2 = again.forward(Tensor::<4>::from_data(
            TensorData::new(input, shape),
            &device,
        ));
        let got2 = y2.into_data().try_to_vec::<f32>().unwrap_or_default();
        assert_eq!(max_abs_diff(&got, &got2), 0.0, "{name}: export round trip");
    }
}
