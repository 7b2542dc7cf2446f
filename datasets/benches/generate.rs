//! One generated item on the bundled northwestern_nu map: rendering alone, and rendering
//! plus the two PNG encodings that `dataset generate` writes (256 × 256, the speed
//! target's size). Single-threaded: `dataset generate` runs one item per thread.

use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

use criterion::{Criterion, criterion_group, criterion_main};
use datasets::generate::{GenerateConfig, Generator, Workspace};
use datasets::image_io::{encode_label_png, encode_rgb_png};

fn generate(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/osm/northwestern_nu.osm.pbf");
    let Ok(map) = maps::import_file(&path, &maps::ImportOptions::default()) else {
        return;
    };
    let mut config = GenerateConfig::default();
    config.camera.width = 256;
    config.camera.height = 256;
    let Ok(generator) = Generator::new(&map, config, 0) else {
        return;
    };
    let mut group = c.benchmark_group("generate_256");
    group
        .sample_size(20)
        .measurement_time(Duration::from_secs(10));
    let mut work = Workspace::default();
    let mut index = 0u64;
    group.bench_function("render", |b| {
        b.iter(|| {
            index += 1;
            black_box(generator.item(index % 500, &mut work).is_ok())
        })
    });
    group.bench_function("render_and_encode", |b| {
        b.iter(|| {
            index += 1;
            if let Ok(item) = generator.item(index % 500, &mut work) {
                black_box(encode_rgb_png(&item.image).len() + encode_label_png(&item.label).len());
            }
        })
    });
    group.finish();
}

criterion_group!(benches, generate);
criterion_main!(benches);
