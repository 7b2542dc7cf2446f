//! Training tests with tiny budgets (the determinism and resume
//! guarantees): a tiny network overfits 4 synthetic 32×32 images to mIoU ≥ 0.95; the same
//! seed gives byte-identical models with 1 and 2 threads; a run resumed from a checkpoint
//! ends exactly where an uninterrupted run ends.

use std::path::{Path, PathBuf};

use burn::tensor::Device;
use models::segmenter::PspNetConfig;
use models::segmenter::data::{Source, SourceSpec, Split};
use models::segmenter::synthetic::write_synthetic_dataset;
use models::segmenter::train::{
    BEST_DIR, CURVES_FILE, CurvePoint, Quiet, StopReason, TrainData, TrainingConfig, train,
};

const SIDE: u32 = 32;

/// Writes the 4-image synthetic dataset (no splits) into `dir`.
fn write_dataset(dir: &Path) -> PathBuf {
    write_synthetic_dataset(dir, 4, SIDE, 0, None).unwrap_or_else(|e| panic!("{e}"));
    dir.to_path_buf()
}

/// The same 4 images to train and to validate on.
fn data(dir: &Path) -> TrainData {
    let spec = SourceSpec {
        path: dir.to_path_buf(),
        weight: 1.0,
    };
    let open = || Source::open(&spec, Split::All).unwrap_or_else(|e| panic!("{e}"));
    TrainData {
        train: vec![open()],
        val: vec![open()],
    }
}

/// A tiny network for 32×32 images: width 1/8, one block per stage, skip refinement.
fn tiny_config(epochs: usize) -> TrainingConfig {
    let model = PspNetConfig::new()
        .with_width(0.125)
        .with_blocks(vec![1, 1, 1, 1])
        .with_psp_channels(16)
        .with_skip_channels(8)
        .with_dropout(0.0)
        .with_mean([128.0; 3])
        .with_std([64.0; 3]);
    TrainingConfig::new(model)
        .with_learning_rate(1e-2)
        .with_batch_size(4)
        .with_epochs(epochs)
        .with_size(SIDE)
        .with_crop(SIDE)
        .with_scale([1.0, 1.0])
        .with_flip(false)
        .with_preview_images(0)
        .with_seed(5)
}

fn curves(run: &Path) -> Vec<CurvePoint> {
    std::fs::read_to_string(run.join(CURVES_FILE))
        .unwrap_or_default()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{l}: {e}")))
        .collect()
}

/// The validation mIoU of each epoch of a run, in order.
fn val_mious(run: &Path) -> Vec<f64> {
    curves(run)
        .iter()
        .filter_map(|p| match p {
            CurvePoint::Epoch(e) => Some(e.val.miou),
            CurvePoint::Step(_) => None,
        })
        .collect()
}

/// The loss of each optimiser step of a run, in order.
fn step_losses(run: &Path) -> Vec<f64> {
    curves(run)
        .iter()
        .filter_map(|p| match p {
            CurvePoint::Step(s) => Some(s.loss),
            CurvePoint::Epoch(_) => None,
        })
        .collect()
}

fn read(dir: &Path, file: &str) -> Vec<u8> {
    std::fs::read(dir.join(file)).unwrap_or_else(|e| panic!("{}: {e}", dir.join(file).display()))
}

/// A fresh (or, with `resume`, continued) run of `config` in `root/name` on the flex backend.
fn run_in(
    root: &Path,
    name: &str,
    config: &TrainingConfig,
    data: &TrainData,
    resume: bool,
) -> PathBuf {
    let dir = root.join(name);
    train(&dir, config, data, resume, &Device::flex(), &mut Quiet)
        .unwrap_or_else(|e| panic!("{e}"));
    dir
}

/// A new run into `run` on the flex backend, training and validating on `dataset`.
fn train_fresh(
    run: &Path,
    config: &TrainingConfig,
    dataset: &Path,
) -> models::segmenter::Result<models::segmenter::train::TrainSummary> {
    train(
        run,
        config,
        &data(dataset),
        false,
        &Device::flex(),
        &mut Quiet,
    )
}

#[test]
fn tiny_network_overfits_four_images() {
    let root = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let dataset = write_dataset(&root.path().join("data"));
    let run = root.path().join("run");
    let config = tiny_config(150).with_patience(Some(150));
    let summary = train_fresh(&run, &config, &dataset).unwrap_or_else(|e| panic!("{e}"));
    assert!(
        summary.state.best_miou >= 0.95,
        "best validation mIoU {} after {} epochs",
        summary.state.best_miou,
        summary.state.epochs_done
    );
    assert_eq!(summary.state.stopped, Some(StopReason::Epochs));
    assert!(run.join(BEST_DIR).join("model.safetensors").is_file());
    // The loss went down.
    let losses = step_losses(&run);
    assert_eq!(losses.len(), 150);
    assert!(
        losses[149] < losses[0] / 5.0,
        "{} -> {}",
        losses[0],
        losses[149]
    );
}

#[test]
fn bf16_convolutions_are_refused_off_libtorch_before_the_run_folder_is_made() {
    let root = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let dataset = write_dataset(&root.path().join("data"));
    let run = root.path().join("run");
    let config = tiny_config(1).with_bf16_convolutions(true);
    let error = train_fresh(&run, &config, &dataset)
        .err()
        .unwrap_or_else(|| panic!("bf16 convolutions trained on the flex backend"));
    assert!(error.to_string().contains("LibTorch"), "{error}");
    assert!(!run.exists(), "the refused run left {}", run.display());
}

fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn same_seed_same_model_whatever_the_threads_and_resume_continues_exactly() {
    let root = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let dataset = write_dataset(&root.path().join("data"));
    let data = data(&dataset);
    let device = Device::flex();
    let run = |name: &str, epochs: usize, threads: usize, resume: bool| {
        let dir = root.path().join(name);
        pool(threads).install(|| {
            train(
                &dir,
                &tiny_config(epochs),
                &data,
                resume,
                &device,
                &mut Quiet,
            )
            .unwrap_or_else(|e| panic!("{e}"))
        });
        dir
    };
    // Files compared by content; a short fingerprint keeps a failure message readable.
    let bytes = |dir: &Path, file: &str| {
        let b = std::fs::read(dir.join(file)).unwrap_or_else(|e| panic!("{e}"));
        let sum = b.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &x| {
            (h ^ u64::from(x)).wrapping_mul(0x0100_0000_01b3)
        });
        (b.len(), sum)
    };
    let one = run("one", 4, 1, false);
    let two = run("two", 4, 2, false);
    assert_eq!(
        bytes(&one, "checkpoint/model.bpk"),
        bytes(&two, "checkpoint/model.bpk")
    );
    assert_eq!(
        bytes(&one, "best/model.safetensors"),
        bytes(&two, "best/model.safetensors")
    );

    // 2 epochs, then resumed for 4: the same end as 4 straight.
    run("resumed", 2, 2, false);
    let resumed = run("resumed", 4, 2, true);
    assert_eq!(
        bytes(&one, "checkpoint/model.bpk"),
        bytes(&resumed, "checkpoint/model.bpk")
    );
    let steps = |dir: &Path| -> Vec<u64> {
        curves(dir)
            .iter()
            .filter_map(|p| match p {
                CurvePoint::Step(s) => Some(s.step),
                CurvePoint::Epoch(_) => None,
            })
            .collect()
    };
    assert_eq!(steps(&resumed), vec![1, 2, 3, 4]);
    assert_eq!(val_mious(&one), val_mious(&resumed));
    // A fresh run into a used folder is refused.
    let again = train(&one, &tiny_config(4), &data, false, &device, &mut Quiet);
    assert!(again.is_err());
}

#[test]
fn the_weight_average_is_validated_saved_and_resumed_exactly() {
    let root = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let dataset = write_dataset(&root.path().join("data"));
    let data = data(&dataset);
    let run = |name: &str, epochs: usize, ema_decay: f64, resume: bool| {
        let config = tiny_config(epochs).with_ema_decay(ema_decay);
        run_in(root.path(), name, &config, &data, resume)
    };
    let plain = run("plain", 4, 0.0, false);
    let averaged = run("averaged", 4, 0.5, false);
    assert!(!plain.join("checkpoint/ema.bpk").exists());
    // The trained weights take the same steps; the average is another network, and it is
    // the one validated.
    assert_eq!(
        read(&plain, "checkpoint/model.bpk"),
        read(&averaged, "checkpoint/model.bpk")
    );
    assert_ne!(
        read(&averaged, "checkpoint/ema.bpk"),
        read(&averaged, "checkpoint/model.bpk")
    );
    assert_ne!(val_mious(&plain), val_mious(&averaged));
    // 2 epochs, then resumed for 4: the same average and the same best model.
    run("resumed", 2, 0.5, false);
    let resumed = run("resumed", 4, 0.5, true);
    for file in ["checkpoint/ema.bpk", "best/model.safetensors"] {
        assert_eq!(read(&averaged, file), read(&resumed, file), "{file}");
    }
    assert_eq!(val_mious(&averaged), val_mious(&resumed));
}

#[test]
fn batch_norm_recalibration_changes_only_the_statistics_and_resumes_exactly() {
    let root = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let dataset = write_dataset(&root.path().join("data"));
    let data = data(&dataset);
    let run = |name: &str, epochs: usize, batches: usize, resume: bool| {
        let config = tiny_config(epochs).with_recalibration_batches(batches);
        run_in(root.path(), name, &config, &data, resume)
    };
    let plain = run("plain", 3, 0, false);
    let recalibrated = run("recalibrated", 3, 3, false);
    // Training normalises with each batch's statistics, so the steps are the same; the
    // running statistics, which the saved model keeps, are not.
    assert_eq!(step_losses(&plain), step_losses(&recalibrated));
    assert_ne!(
        read(&plain, "checkpoint/model.bpk"),
        read(&recalibrated, "checkpoint/model.bpk")
    );
    // 2 epochs, then resumed for 3: the same model.
    run("resumed", 2, 3, false);
    let resumed = run("resumed", 3, 3, true);
    for file in ["checkpoint/model.bpk", "best/model.safetensors"] {
        assert_eq!(read(&recalibrated, file), read(&resumed, file), "{file}");
    }
    assert_eq!(val_mious(&recalibrated), val_mious(&resumed));
    // Recalibrating a weight average is refused before anything is written.
    let both = tiny_config(1)
        .with_recalibration_batches(3)
        .with_ema_decay(0.5);
    let refused = root.path().join("both");
    let error = train(&refused, &both, &data, false, &Device::flex(), &mut Quiet)
        .err()
        .unwrap_or_else(|| panic!("recalibration of a weight average was accepted"));
    assert!(error.to_string().contains("weight average"), "{error}");
    assert!(!refused.exists());
}
