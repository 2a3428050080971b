//! NXT direct-command telegrams: encoding the bridge's SETOUTPUTSTATE request and decoding the
//! brick's GETOUTPUTSTATE reply — the codec work of every action.

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use tes_bridge::nxt::{
    Mode, OutputState, Port, PortSelector, RegulationMode, Reply, Request, RunState,
    SetOutputState, Status,
};

fn bench_nxt(c: &mut Criterion) {
    let mut group = c.benchmark_group("nxt");
    let set = Request::SetOutputState(SetOutputState {
        port: PortSelector::One(Port::B),
        power: 75,
        mode: Mode::MOTOR_ON,
        regulation: RegulationMode::Speed,
        turn_ratio: 0,
        run_state: RunState::Running,
        tacho_limit: 246,
    });
    group.bench_function(BenchmarkId::new("encode", "SETOUTPUTSTATE"), |b| {
        b.iter(|| black_box(black_box(&set).encode(false)))
    });
    let reply = Reply::OutputState {
        status: Status::Success,
        state: OutputState {
            port: Port::B,
            power: 75,
            mode: Mode::MOTOR_ON,
            regulation: RegulationMode::Speed,
            turn_ratio: 0,
            run_state: RunState::Idle,
            tacho_limit: 246,
            tacho_count: 251,
            block_tacho_count: 251,
            rotation_count: 1_234,
        },
    }
    .encode();
    let bytes = reply.as_bytes().to_vec();
    group.bench_function(BenchmarkId::new("decode", "GETOUTPUTSTATE reply"), |b| {
        b.iter(|| black_box(Reply::decode(black_box(&bytes))))
    });
    let request = set.encode(false).as_bytes().to_vec();
    group.bench_function(BenchmarkId::new("decode", "SETOUTPUTSTATE"), |b| {
        b.iter(|| black_box(Request::decode(black_box(&request))))
    });
    group.finish();
}

criterion_group!(benches, bench_nxt);
criterion_main!(benches);
