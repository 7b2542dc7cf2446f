//! Building the map from already parsed OSM data (northwestern_nu, default options).

use std::hint::black_box;
use std::time::Duration;

use criterion::{Criterion, criterion_group, criterion_main};
use maps::ImportOptions;

mod common;

fn build(c: &mut Criterion) {
    let mut group = c.benchmark_group("build");
    group
        .sample_size(10)
        .measurement_time(Duration::from_secs(10));
    for name in ["northwestern_nu.osm.pbf"] {
        let Some(path) = common::osm_file(name) else {
            continue;
        };
        let Ok((osm, _)) = maps::osm::read_osm_file(&path) else {
            continue;
        };
        let options = ImportOptions::default();
        group.bench_function(name, |b| {
            b.iter(|| black_box(maps::import_osm(&osm, &options).is_ok()))
        });
    }
    group.finish();
}

criterion_group!(benches, build);
criterion_main!(benches);
