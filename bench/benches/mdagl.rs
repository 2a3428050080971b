//! mDAGL predict and update throughput.
//!
//! Two shapes: the robot arenas' sparse binary input (d = 312 features, K = 20 effects, ~15
//! features on per row) and the grid tasks' dense input (d = 210, K = 5). Rows are drawn from
//! a seeded sparse ground-truth model before timing; each timed call consumes the next row.
//! Design target: ≥ 1 000 000 sparse updates per second on one core.

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use tes_learning::mdagl::synthetic::{SparseMultinomialStream, SyntheticSpec};
use tes_learning::mdagl::{Features, Mdagl, MdaglParams};

const ROWS: usize = 4096;
const SEED: u64 = 2017;

struct Shape {
    name: &'static str,
    classes: usize,
    features: usize,
    active: f64,
    dense: bool,
}

const SHAPES: [Shape; 2] = [
    Shape {
        name: "sparse",
        classes: 20,
        features: 312,
        active: 15.0,
        dense: false,
    },
    Shape {
        name: "dense",
        classes: 5,
        features: 210,
        active: 105.0,
        dense: true,
    },
];

/// Pre-drawn rows: labels, sparse index lists and the same rows densified.
fn rows(shape: &Shape) -> (Vec<usize>, Vec<Vec<u32>>, Vec<Vec<f64>>) {
    let spec = SyntheticSpec {
        classes: shape.classes,
        features: shape.features,
        relevant: 10,
        density: shape.active / shape.features as f64,
        bias: true,
        weight_scale: 3.0,
    };
    let mut stream = SparseMultinomialStream::new(spec, SEED).expect("valid spec");
    let mut labels = Vec::with_capacity(ROWS);
    let mut sparse = Vec::with_capacity(ROWS);
    let mut dense = Vec::with_capacity(ROWS);
    for _ in 0..ROWS {
        let (y, x) = stream.next_row();
        labels.push(y);
        let mut d = vec![0.0; shape.features];
        for &i in x {
            // Real-valued input for the dense shape, so it exercises the general path.
            d[i as usize] = 0.5 + (i % 7) as f64 / 7.0;
        }
        sparse.push(x.to_vec());
        dense.push(d);
    }
    (labels, sparse, dense)
}

fn features<'a>(shape: &Shape, sparse: &'a [u32], dense: &'a [f64]) -> Features<'a> {
    if shape.dense {
        Features::Dense(dense)
    } else {
        Features::SparseBinary(sparse)
    }
}

fn bench_mdagl(c: &mut Criterion) {
    let mut group = c.benchmark_group("mdagl");
    group.throughput(Throughput::Elements(1));
    for shape in &SHAPES {
        let (labels, sparse, dense) = rows(shape);
        let id = format!("{}/d={}/K={}", shape.name, shape.features, shape.classes);
        let params = MdaglParams::default();

        // A model that has already seen a stream, so columns are selected as in use.
        let mut warm = Mdagl::new(shape.classes, shape.features, params).expect("valid model");
        for i in 0..ROWS {
            warm.update(features(shape, &sparse[i], &dense[i]), labels[i])
                .expect("valid row");
        }

        let mut model = warm.clone();
        let mut i = 0;
        group.bench_function(BenchmarkId::new("update", &id), |b| {
            b.iter(|| {
                let x = features(shape, &sparse[i], &dense[i]);
                let out = model.update(black_box(x), labels[i]).expect("valid row");
                i = (i + 1) % ROWS;
                out
            })
        });

        let mut probs = vec![0.0; shape.classes];
        let mut j = 0;
        group.bench_function(BenchmarkId::new("predict", &id), |b| {
            b.iter(|| {
                let x = features(shape, &sparse[j], &dense[j]);
                warm.predict_into(black_box(x), &mut probs)
                    .expect("valid row");
                j = (j + 1) % ROWS;
                probs[0]
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench_mdagl);
criterion_main!(benches);
