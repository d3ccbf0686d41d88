//! One case-1 fibre settling under gravity along x in still fluid, two-way (through the flow
//! node's stages) beside one-way: prints t+, both mean x velocities and their ratio as CSV.
//! docs/two-way.md quotes its output.
//!
//! `cargo run --release -p fiberflow-flow --example settling -- [coarse|fine] [history|none] [t_plus] [segments]`
//! `cargo run --release -p fiberflow-flow --example settling -- [coarse|fine] probe [t_plus]`:
//! a unit force held at one point, the DNS's disturbance there against the memories' estimate.

#[path = "../tests/common/settling.rs"]
mod settling;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let fine = args.get(1).is_some_and(|s| s == "fine");
    let correct = args.get(2).is_none_or(|s| s == "history");
    let t_end: f64 = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(150.0);
    let segments: usize = args.get(4).and_then(|s| s.parse().ok()).unwrap_or(7);
    if args.get(2).is_some_and(|s| s == "probe") {
        println!("t_plus,dns,memories,ratio");
        for [t, dns, model] in settling::probe(fine, t_end, 25) {
            println!("{t:.1},{dns:.6e},{model:.6e},{:.4}", model / dns);
        }
        return;
    }
    println!("t_plus,u_one_way,u_two_way,ratio");
    for [t, a, b] in settling::settle(fine, correct, t_end, segments, 25) {
        println!("{t:.1},{a:.6},{b:.6},{:.4}", b / a);
    }
}
