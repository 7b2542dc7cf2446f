//! Times the DQN gradient step of `models::dqn::Learner::learn` — the one training runs —
//! for the speed comparison with PyTorch (`scripts/bench_qnet.py` runs this in release mode
//! with `RAYON_NUM_THREADS` set, next to the same network and step in PyTorch).
//!
//! One step: the target network on the next observations, the online network on them
//! (Double DQN's action choice), the online network on the observations with gradients,
//! the Huber TD loss, backward, Adam. Input: `[batch, 16, 84, 84]` layers (4 layers × 4
//! frames) and 6 scalars, 3 actions; the batch is random and rebuilt outside the timing.
//!
//! Usage: `bench_qnet_step [--network default|its] [--batch 32] [--steps 60] [--warmup 5]
//! [--device cpu|libtorch] [--size 84] [--channels 16] [--convs C:K:S:P,...]`; prints one JSON
//! object. `--size` and `--channels` set the input (`[batch, channels, size, size]`), `--convs`
//! replaces the preset's convolutions (channels:kernel:stride:padding each), to time a network
//! before an hour of training on it. `libtorch` needs a build with
//! `--features libtorch` (docs/gpu.md); its threads are capped at `RAYON_NUM_THREADS` too.

#![allow(clippy::print_stdout, clippy::print_stderr)]

use std::time::Instant;

// The `pipeline` binary's allocator and its settings (models::allocator), so the step is timed
// as training runs it.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

use models::dqn::{AgentShape, DqnConfig, Learner};
use models::qnet::{ConvSpec, QNetworkConfig};
use models::replay::Batch;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn arg<T: std::str::FromStr>(args: &[String], name: &str, default: T) -> T {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn random_batch(rng: &mut ChaCha8Rng, shape: &AgentShape, size: usize) -> Batch {
    let layers = size * shape.channels * shape.height * shape.width;
    let mut values = |n: usize| {
        (0..n)
            .map(|_| f32::from(rng.random_range(0u8..2) * 255) / 255.0)
            .collect::<Vec<f32>>()
    };
    let (l, nl) = (values(layers), values(layers));
    let (s, ns) = (values(size * shape.scalars), values(size * shape.scalars));
    Batch {
        size,
        layers: l,
        scalars: s,
        actions: (0..size)
            .map(|_| rng.random_range(0..shape.actions))
            .collect(),
        returns: (0..size).map(|_| rng.random_range(-1.0..1.0)).collect(),
        discounts: vec![0.99f32.powi(3); size],
        next_layers: nl,
        next_scalars: ns,
        weights: vec![1.0; size],
        leaves: vec![0; size],
    }
}

/// `channels:kernel:stride:padding[,...]` as convolution specs.
fn parse_convolutions(text: &str) -> Option<Vec<ConvSpec>> {
    text.split(',')
        .map(|spec| {
            let v: Vec<usize> = spec
                .split(':')
                .map(|x| x.parse().ok())
                .collect::<Option<_>>()?;
            match v[..] {
                [channels, kernel, stride, padding] => Some(ConvSpec {
                    channels,
                    kernel,
                    stride,
                    padding,
                }),
                _ => None,
            }
        })
        .collect()
}

fn main() {
    models::allocator::keep_freed_memory();
    let args: Vec<String> = std::env::args().collect();
    let network: String = arg(&args, "--network", "default".to_owned());
    let batch_size: usize = arg(&args, "--batch", 32);
    let steps: usize = arg(&args, "--steps", 60);
    let warmup: usize = arg(&args, "--warmup", 5);
    let device_name: String = arg(&args, "--device", "cpu".to_owned());
    let (choice, framework) = match device_name.as_str() {
        "cpu" => (models::DeviceChoice::Cpu, "burn 0.22.1 flex"),
        "libtorch" => (models::DeviceChoice::LibTorch, "burn 0.22.1 libtorch"),
        other => {
            eprintln!("unknown --device {other} (cpu or libtorch)");
            std::process::exit(2);
        }
    };
    let device = match models::device(choice) {
        Ok(d) => d,
        Err(e) => {
            eprintln!("--device {device_name}: {e}: build with --features {device_name}");
            std::process::exit(2);
        }
    };
    let threads = rayon::current_num_threads();
    models::set_network_threads(threads);
    let Some(mut network_config) = QNetworkConfig::preset(&network) else {
        eprintln!("unknown --network {network} (default or its)");
        std::process::exit(2);
    };
    let convs: String = arg(&args, "--convs", String::new());
    if !convs.is_empty() {
        match parse_convolutions(&convs) {
            Some(c) => network_config.convolutions = c,
            None => {
                eprintln!("--convs {convs}: expected channels:kernel:stride:padding[,...]");
                std::process::exit(2);
            }
        }
    }
    let size: usize = arg(&args, "--size", 84);
    let config = DqnConfig {
        network: network_config,
        batch_size,
        // The PyTorch side clips nothing either.
        gradient_clip_norm: 0.0,
        ..DqnConfig::default()
    };
    let shape = AgentShape {
        channels: arg(&args, "--channels", 16),
        height: size,
        width: size,
        scalars: 6,
        actions: 3,
    };
    let mut learner = match Learner::new(&config, &shape, 0, &device) {
        Ok(l) => l,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(1);
        }
    };
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut times_ms = Vec::with_capacity(steps);
    let mut losses = Vec::new();
    for i in 0..warmup + steps {
        let batch = random_batch(&mut rng, &shape, batch_size);
        let start = Instant::now();
        let (loss, _, _) = learner.learn(batch);
        let elapsed = start.elapsed().as_secs_f64() * 1e3;
        if i >= warmup {
            times_ms.push(elapsed);
            losses.push(loss);
        }
    }
    let mut sorted = times_ms.clone();
    sorted.sort_by(f64::total_cmp);
    let median = if sorted.is_empty() {
        f64::NAN
    } else {
        sorted[sorted.len() / 2]
    };
    println!(
        "{{\"framework\": \"{framework}\", \"network\": \"{network}\", \"batch\": {batch_size}, \"threads\": {threads}, \
         \"input\": [{}, {size}, {size}], \"steps\": {steps}, \"median_ms\": {median:.3}, \"times_ms\": {times_ms:?}, \"last_loss\": {:.6}}}",
        shape.channels,
        losses.last().copied().unwrap_or(f64::NAN)
    );
}
