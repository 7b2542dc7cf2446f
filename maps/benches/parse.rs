//! Parsing OSM input: northwestern_nu as XML and as PBF (the same data).

use std::hint::black_box;
use std::time::Duration;

use criterion::{Criterion, criterion_group, criterion_main};

mod common;

fn parse(c: &mut Criterion) {
    let mut group = c.benchmark_group("parse");
    group
        .sample_size(10)
        .measurement_time(Duration::from_secs(10));
    for name in ["northwestern_nu.osm", "northwestern_nu.osm.pbf"] {
        let Some(path) = common::osm_file(name) else {
            continue;
        };
        group.bench_function(name, |b| {
            b.iter(|| black_box(maps::osm::read_osm_file(&path).is_ok()))
        });
    }
    group.finish();
}

criterion_group!(benches, parse);
criterion_main!(benches);
