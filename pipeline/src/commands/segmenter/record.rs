//! What `segmenter train` shows while it runs: progress lines, and the rerun recording.
//!
//! | entity | timeline | what |
//! | --- | --- | --- |
//! | `segmenter/train/loss`, `segmenter/train/learning_rate` | `step` | each optimiser step |
//! | `segmenter/val/miou`, `segmenter/val/pixel_accuracy`, `segmenter/val/iou/<class>` | `epoch` (and `step`) | each validation |
//! | `segmenter/val/<source>/miou` | `epoch` | per validation dataset |
//! | `segmenter/val/images/<i>/{image,prediction,label}` | `epoch` | fixed validation images |
//!
//! A resumed run logs the curves it kept (`curves.jsonl`) first, so the new recording holds
//! the whole run.

use crate::recording::Stream;
use anyhow::Result;
use models::segmenter::eval::{Prediction, class_names};
use models::segmenter::train::{CurvePoint, EpochPoint, StepPoint, TrainObserver};

use crate::recording::{Recording, log_class_context_at, log_rgb, log_scalars, log_segmentation};
use crate::ui::Progress;

/// Root entity of the segmenter's recording.
pub const SEGMENTER_ENTITY: &str = "segmenter";

/// The training run's observer: progress lines and rerun.
pub struct TrainRecorder<'a, 'p> {
    rec: Option<&'a Stream>,
    progress: &'a mut Progress<'p>,
    classes: Vec<String>,
    /// The first rerun error; training goes on without the recording, and the error is
    /// reported at the end.
    error: Option<anyhow::Error>,
    epoch_started: bool,
}

impl std::fmt::Debug for TrainRecorder<'_, '_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TrainRecorder")
            .field("recording", &self.rec.is_some())
            .finish_non_exhaustive()
    }
}

impl<'a, 'p> TrainRecorder<'a, 'p> {
    pub fn new(
        recording: &'a Recording,
        progress: &'a mut Progress<'p>,
        classes: usize,
    ) -> Result<Self> {
        let rec = recording.stream();
        if let Some(rec) = rec {
            log_class_context_at(rec, SEGMENTER_ENTITY)?;
        }
        Ok(TrainRecorder {
            rec,
            progress,
            classes: class_names(classes),
            error: None,
            epoch_started: false,
        })
    }

    /// The first recording error, if any.
    pub fn finish(self) -> Result<()> {
        self.error.map_or(Ok(()), Err)
    }

    fn log(&mut self, f: impl FnOnce(&Stream, &[String]) -> Result<()>) {
        if self.error.is_some() {
            return;
        }
        if let Some(rec) = self.rec
            && let Err(e) = f(rec, &self.classes)
        {
            self.error = Some(e);
        }
    }
}

fn log_step(rec: &Stream, p: &StepPoint) -> Result<()> {
    rec.set_time_sequence("step", p.step as i64);
    log_scalars(
        rec,
        &[
            ("segmenter/train/loss", p.loss),
            ("segmenter/train/learning_rate", p.learning_rate),
        ],
    )
}

fn log_epoch(rec: &Stream, p: &EpochPoint, classes: &[String]) -> Result<()> {
    rec.set_time_sequence("step", p.step as i64);
    rec.set_time_sequence("epoch", p.epoch as i64);
    let mut series: Vec<(String, f64)> = vec![
        ("segmenter/val/miou".into(), p.val.miou),
        ("segmenter/val/pixel_accuracy".into(), p.val.pixel_accuracy),
        ("segmenter/train/epoch_loss".into(), p.train_loss),
    ];
    for name in classes {
        if let Some(iou) = p.val.per_class_iou.get(name) {
            series.push((format!("segmenter/val/iou/{name}"), *iou));
        }
    }
    for (source, m) in &p.val_per_source {
        series.push((format!("segmenter/val/{source}/miou"), m.miou));
    }
    let refs: Vec<(&str, f64)> = series.iter().map(|(e, v)| (e.as_str(), *v)).collect();
    log_scalars(rec, &refs)
}

fn log_previews(rec: &Stream, previews: &[Prediction]) -> Result<()> {
    for (i, p) in previews.iter().enumerate() {
        let base = format!("{SEGMENTER_ENTITY}/val/images/{i}");
        log_rgb(rec, &format!("{base}/image"), &p.sample.image)?;
        log_segmentation(rec, &format!("{base}/prediction"), &p.prediction)?;
        log_segmentation(rec, &format!("{base}/label"), &p.sample.label)?;
    }
    Ok(())
}

impl TrainObserver for TrainRecorder<'_, '_> {
    fn history(&mut self, points: &[CurvePoint]) {
        let epochs = points
            .iter()
            .filter(|p| matches!(p, CurvePoint::Epoch(_)))
            .count();
        self.progress.note(&format!(
            "resuming after epoch {epochs} ({} curve points kept)",
            points.len()
        ));
        self.log(|rec, classes| {
            for p in points {
                match p {
                    CurvePoint::Step(s) => log_step(rec, s)?,
                    CurvePoint::Epoch(e) => log_epoch(rec, e, classes)?,
                }
            }
            Ok(())
        });
    }

    fn step(&mut self, point: &StepPoint) {
        self.log(|rec, _| log_step(rec, point));
    }

    fn epoch(&mut self, point: &EpochPoint, previews: &[Prediction]) {
        self.epoch_started = false;
        let per_class: Vec<String> = point
            .val
            .per_class_iou
            .iter()
            .map(|(name, iou)| format!("{name} {iou:.3}"))
            .collect();
        self.progress.note(&format!(
            "epoch {}: train loss {:.4}, val mIoU {:.4}{} ({}), {:.0} s",
            point.epoch,
            point.train_loss,
            point.val.miou,
            if point.best { " (best)" } else { "" },
            per_class.join(", "),
            point.seconds
        ));
        self.log(|rec, classes| {
            log_epoch(rec, point, classes)?;
            log_previews(rec, previews)
        });
    }

    fn progress(&mut self, what: &str, done: usize, total: usize) {
        if what == "train" && !self.epoch_started {
            self.epoch_started = true;
            self.progress.step(&format!("training ({total} batches)"));
        } else if what == "validate" && done == 1 {
            self.progress.step(&format!("validating ({total} images)"));
        }
    }
}
