//! The segmenter's architecture options, shared by `train` and `bench`.

use clap::{Args, ValueEnum};
use models::segmenter::PspNetConfig;

/// The architecture options (of `train`, and of `bench` without a model).
#[derive(Debug, Args)]
pub struct ArchArgs {
    /// Encoder blocks [default: resnet18].
    #[arg(long, value_enum)]
    pub encoder: Option<EncoderArg>,

    /// Channel multiplier of the encoder [default: 1].
    #[arg(long)]
    pub width: Option<f64>,

    /// Encoder depth: 3 is output stride 8 [default: 3].
    #[arg(long)]
    pub depth: Option<usize>,

    /// Dilate stages 3 and 4 instead of striding.
    #[arg(long)]
    pub dilated: bool,

    /// Pyramid pooling output channels [default: 512].
    #[arg(long, value_name = "N")]
    pub psp_channels: Option<usize>,

    /// Channels of the stride-8 skip refinement, on stage 2's output (depth 4 and 5) [default: 0, off].
    #[arg(long, value_name = "N")]
    pub mid_skip_channels: Option<usize>,

    /// Channels of the stride-4 skip refinement [default: 0, off].
    #[arg(long, value_name = "N")]
    pub skip_channels: Option<usize>,

    /// Channels of the stride-2 skip refinement, on the stem's output [default: 0, off].
    #[arg(long, value_name = "N")]
    pub fine_skip_channels: Option<usize>,

    /// Train with an auxiliary head on the second-to-last encoder stage.
    #[arg(long)]
    pub aux_head: bool,
}

impl ArchArgs {
    /// Applies the options given to `m`.
    pub fn apply(&self, m: &mut PspNetConfig) {
        if let Some(e) = self.encoder {
            m.blocks = match e {
                EncoderArg::Resnet18 => vec![2, 2, 2, 2],
                EncoderArg::Resnet34 => vec![3, 4, 6, 3],
            };
        }
        set(&mut m.width, self.width);
        set(&mut m.depth, self.depth);
        set(&mut m.psp_channels, self.psp_channels);
        set(&mut m.mid_skip_channels, self.mid_skip_channels);
        set(&mut m.skip_channels, self.skip_channels);
        set(&mut m.fine_skip_channels, self.fine_skip_channels);
        m.dilated |= self.dilated;
        m.aux_head |= self.aux_head;
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum EncoderArg {
    Resnet18,
    Resnet34,
}

/// Puts `value` in `slot` when it is given.
pub fn set<T>(slot: &mut T, value: Option<T>) {
    if let Some(v) = value {
        *slot = v;
    }
}
