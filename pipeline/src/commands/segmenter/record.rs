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
//! the whole run. After each epoch the curves so far are drawn into `curves.png` in the run
//! folder (the loss per step and per epoch, the validation mIoU and pixel accuracy per
//! epoch).
//!
//! The progress bar counts optimiser steps of the whole run and shows the epoch, the loss
//! of the last step and the last validation mIoU.

use std::path::PathBuf;

use crate::recording::Stream;
use anyhow::Result;
use models::segmenter::eval::{Prediction, class_names};
use models::segmenter::train::{CurvePoint, EpochPoint, StepPoint, TrainObserver, TrainPlan};

use crate::plots::{SegmenterCurves, segmenter_curves_png, write_png};
use crate::recording::{Recording, log_class_context_at, log_rgb, log_scalars, log_segmentation};
use crate::ui::Progress;

/// Root entity of the segmenter's recording.
pub const SEGMENTER_ENTITY: &str = "segmenter";

/// The training curves' picture in the run folder.
pub const CURVES_PNG: &str = "curves.png";

/// The training run's observer: progress bar, log lines, curves.png and rerun.
pub struct TrainRecorder<'a, 'p> {
    rec: Option<&'a Stream>,
    progress: &'a mut Progress<'p>,
    classes: Vec<String>,
    /// The first rerun or plot error; training goes on without the recording, and the
    /// error is reported at the end.
    error: Option<anyhow::Error>,
    plan: Option<TrainPlan>,
    /// The epoch being trained (1-based), the last step's loss, the last validation mIoU.
    epoch: usize,
    last_loss: Option<f64>,
    last_miou: Option<f64>,
    /// Seconds into the run at the last step, for -v's step timings.
    last_step_seconds: Option<f64>,
    curves: SegmenterCurves,
    curves_png: PathBuf,
}

impl std::fmt::Debug for TrainRecorder<'_, '_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TrainRecorder")
            .field("recording", &self.rec.is_some())
            .finish_non_exhaustive()
    }
}

impl<'a, 'p> TrainRecorder<'a, 'p> {
    /// Records into `recording` and draws `curves.png` into `run_dir`.
    pub fn new(
        recording: &'a Recording,
        progress: &'a mut Progress<'p>,
        classes: usize,
        run_dir: &std::path::Path,
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
            plan: None,
            epoch: 1,
            last_loss: None,
            last_miou: None,
            last_step_seconds: None,
            curves: SegmenterCurves::default(),
            curves_png: run_dir.join(CURVES_PNG),
        })
    }

    /// The curves so far, as points of the picture.
    fn add_point(&mut self, point: &CurvePoint) {
        match point {
            CurvePoint::Step(p) => self.curves.step_loss.push((p.step, p.loss)),
            CurvePoint::Epoch(p) => {
                self.curves.epoch_loss.push((p.step, p.train_loss));
                self.curves.val_miou.push((p.epoch, p.val.miou));
                self.curves
                    .val_pixel_accuracy
                    .push((p.epoch, p.val.pixel_accuracy));
            }
        }
    }

    /// Draws curves.png (the first error is kept for the end).
    fn draw_curves(&mut self) {
        if self.error.is_some() {
            return;
        }
        if let Err(e) =
            segmenter_curves_png(&self.curves).and_then(|png| write_png(&self.curves_png, &png))
        {
            self.error = Some(e.context(format!("{}", self.curves_png.display())));
        }
    }

    /// The bar's figures: epoch, last loss, last validation mIoU.
    fn show_figures(&self, doing: Option<String>) {
        let mut figures = Vec::new();
        if let Some(plan) = &self.plan {
            figures.push(format!(
                "epoch {}/{}",
                self.epoch.min(plan.epochs),
                plan.epochs
            ));
        }
        if let Some(loss) = self.last_loss {
            figures.push(format!("loss {loss:.4}"));
        }
        if let Some(miou) = self.last_miou {
            figures.push(format!("val mIoU {miou:.4}"));
        }
        if let Some(doing) = doing {
            figures.push(doing);
        }
        self.progress.set_figures(&figures.join(", "));
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
        for p in points {
            self.add_point(p);
        }
        if let Some(CurvePoint::Epoch(last)) = points
            .iter()
            .rev()
            .find(|p| matches!(p, CurvePoint::Epoch(_)))
        {
            self.last_miou = Some(last.val.miou);
        }
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

    fn plan(&mut self, plan: &TrainPlan) {
        self.plan = Some(*plan);
        self.epoch = plan.epochs_done + 1;
        self.progress.counted_with(
            "training",
            plan.total_steps,
            "steps",
            &format!(
                "{} of {}",
                crate::ui::plural(plan.epochs, "epoch"),
                crate::ui::plural(plan.batches_per_epoch, "batch")
            ),
        );
        self.progress.resume_at(plan.steps_done);
        self.show_figures(None);
    }

    fn step(&mut self, point: &StepPoint) {
        if let Some(before) = self.last_step_seconds {
            self.progress.detail(&format!(
                "step {}: loss {:.4}, learning rate {:.3e}, {:.2} s",
                point.step,
                point.loss,
                point.learning_rate,
                point.seconds - before
            ));
        }
        self.last_step_seconds = Some(point.seconds);
        self.epoch = point.epoch;
        self.last_loss = Some(point.loss);
        self.add_point(&CurvePoint::Step(point.clone()));
        self.show_figures(None);
        self.progress.set_position(point.step);
        self.log(|rec, _| log_step(rec, point));
    }

    fn epoch(&mut self, point: &EpochPoint, previews: &[Prediction]) {
        self.last_miou = Some(point.val.miou);
        self.epoch = point.epoch + 1;
        self.add_point(&CurvePoint::Epoch(point.clone()));
        self.draw_curves();
        self.show_figures(None);
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
        if what == "validate" {
            self.show_figures(Some(format!("validating {done}/{total} images")));
            if done == 1 {
                self.progress
                    .detail(&format!("validating {}", crate::ui::plural(total, "image")));
            }
        }
    }
}
