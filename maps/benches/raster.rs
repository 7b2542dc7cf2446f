//! Rasterizing 1 km × 1 km at 0.1 m (10,000 × 10,000 pixels; drivable, markings and lane
//! ids) over the densest part of a map, with fresh and with reused buffers, and an
//! ego-sized crop.

use std::hint::black_box;
use std::time::Duration;

use criterion::{Criterion, criterion_group, criterion_main};
use maps::ImportOptions;
use maps::raster::{Layers, RasterSpec, Rasterizer, rasterize, rasterize_into};

mod common;

fn raster(c: &mut Criterion) {
    let mut group = c.benchmark_group("raster_1km2_0.1m");
    group
        .sample_size(10)
        .measurement_time(Duration::from_secs(20));
    for name in ["northwestern_nu.osm.pbf", "helsinki.osm.pbf"] {
        let Some(path) = common::osm_file(name) else {
            continue;
        };
        let Ok(map) = maps::import_file(&path, &ImportOptions::default()) else {
            continue;
        };
        let spec = common::densest_window(&map, 1000.0, 0.1);
        // Fresh buffers: 600 MB per call, so the kernel's page faults weigh in.
        group.bench_function(format!("{name}/fresh"), |b| {
            b.iter(|| black_box(rasterize(&map, &spec, Layers::ALL).spec.width))
        });
        // Buffers reused from call to call, as a loop of crops would.
        let mut out = rasterize(&map, &spec, Layers::ALL);
        group.bench_function(format!("{name}/reused"), |b| {
            b.iter(|| {
                rasterize_into(&map, Layers::ALL, &mut out);
                black_box(out.spec.width)
            })
        });
        // An ego-sized crop (25.6 m square at 0.1 m) in the middle of that window, with the
        // map prepared once and the buffers reused, as an observation renderer would.
        let mut crop = RasterSpec {
            width: 256,
            height: 256,
            ..spec
        };
        crop.origin.x += 500.0 - 12.8;
        crop.origin.y += 500.0 - 12.8;
        let prepared = Rasterizer::new(&map);
        let mut out = prepared.rasterize(&crop, Layers::ALL);
        group.bench_function(format!("{name}/crop_256px_prepared"), |b| {
            b.iter(|| {
                prepared.rasterize_into(Layers::ALL, &mut out);
                black_box(out.spec.width)
            })
        });
    }
    group.finish();
}

criterion_group!(benches, raster);
criterion_main!(benches);
