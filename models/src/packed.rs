//! Compact storage of `u8` observation layers for the replay buffer.
//!
//! Bird's-eye layers are mostly large uniform areas (empty space, the navigable area, the
//! path), so a run-length code shrinks a 4 × 4 × 84 × 84 stack (112,896 bytes) by roughly an
//! order of magnitude; layers that do not compress (noise, camera images) are kept raw, so
//! the worst case is the raw size plus a byte of tag.

/// A layer byte as the networks see it: 0 → 0.0, 255 → 1.0. Every path from `u8` layers
/// to network inputs goes through this, so acting and learning see identical values.
pub fn scale_layer_byte(b: u8) -> f32 {
    f32::from(b) / 255.0
}

/// One observation's layers, run-length coded or raw.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PackedLayers {
    /// `(value, run length - 1)` byte pairs: runs of 1 to 256 equal bytes.
    Runs(Box<[u8]>),
    Raw(Box<[u8]>),
}

impl PackedLayers {
    pub fn pack(layers: &[u8]) -> Self {
        let mut runs = Vec::with_capacity(layers.len() / 8);
        let mut i = 0;
        while i < layers.len() {
            let value = layers[i];
            let mut run = 1;
            while run < 256 && i + run < layers.len() && layers[i + run] == value {
                run += 1;
            }
            runs.push(value);
            runs.push((run - 1) as u8);
            if runs.len() >= layers.len() {
                return PackedLayers::Raw(layers.into());
            }
            i += run;
        }
        PackedLayers::Runs(runs.into_boxed_slice())
    }

    /// Bytes held (what the replay's memory figure counts).
    pub fn stored_bytes(&self) -> usize {
        match self {
            PackedLayers::Runs(b) | PackedLayers::Raw(b) => b.len(),
        }
    }

    /// Writes the layers scaled to [0, 1] into `out`, which must hold exactly the unpacked
    /// length.
    pub fn unpack_scaled(&self, out: &mut [f32]) {
        match self {
            PackedLayers::Raw(bytes) => {
                for (o, &b) in out.iter_mut().zip(bytes.iter()) {
                    *o = scale_layer_byte(b);
                }
            }
            PackedLayers::Runs(runs) => {
                let mut at = 0;
                for pair in runs.chunks_exact(2) {
                    let run = usize::from(pair[1]) + 1;
                    out[at..at + run].fill(scale_layer_byte(pair[0]));
                    at += run;
                }
                debug_assert_eq!(at, out.len());
            }
        }
    }

    /// The original bytes (tests and recordings).
    pub fn unpack(&self) -> Vec<u8> {
        match self {
            PackedLayers::Raw(bytes) => bytes.to_vec(),
            PackedLayers::Runs(runs) => runs
                .chunks_exact(2)
                .flat_map(|pair| std::iter::repeat_n(pair[0], usize::from(pair[1]) + 1))
                .collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn round_trips_runs_long_runs_and_noise() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut blocky = vec![0u8; 84 * 84 * 16];
        for (i, b) in blocky.iter_mut().enumerate() {
            if (i / 84) % 7 < 3 && i % 84 > 20 {
                *b = 255;
            }
        }
        let noise: Vec<u8> = (0..1000).map(|_| rng.random()).collect();
        let cases = [
            blocky.clone(),
            vec![7u8; 1000],
            noise.clone(),
            vec![],
            vec![9],
            vec![0u8; 256],
            vec![0u8; 257],
        ];
        for case in &cases {
            let packed = PackedLayers::pack(case);
            assert_eq!(&packed.unpack(), case);
            let mut scaled = vec![-1.0f32; case.len()];
            packed.unpack_scaled(&mut scaled);
            for (s, &b) in scaled.iter().zip(case) {
                assert_eq!(*s, scale_layer_byte(b));
            }
        }
        let packed = PackedLayers::pack(&blocky);
        assert!(matches!(packed, PackedLayers::Runs(_)));
        assert!(
            packed.stored_bytes() * 10 < blocky.len(),
            "{}",
            packed.stored_bytes()
        );
        assert!(matches!(PackedLayers::pack(&noise), PackedLayers::Raw(_)));
    }
}
