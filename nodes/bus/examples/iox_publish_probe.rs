use fiberflow_bus::iceoryx2_bus::Iceoryx2Bus;
use fiberflow_bus::Bus;
use std::time::Instant;
fn main() {
    let run = format!("probe{}", std::process::id());
    let topics: Vec<String> = (0..8).map(|i| format!("fiberflow/{run}/t{i}")).collect();
    let n_listeners: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(8);
    let publisher = Iceoryx2Bus::open(&run, topics.clone()).unwrap();
    let others: Vec<_> = (0..n_listeners)
        .map(|_| Iceoryx2Bus::open(&run, topics.clone()).unwrap())
        .collect();
    let subs: Vec<_> = others
        .iter()
        .enumerate()
        .map(|(i, b)| b.subscribe(&topics[i % 8]).unwrap())
        .collect();
    let payload = vec![1u8; 33_000];
    for _ in 0..50 {
        for t in &topics {
            publisher.publish(t, &payload).unwrap();
        }
    }
    std::thread::sleep(std::time::Duration::from_millis(200));
    let t0 = Instant::now();
    let n = 2000;
    for i in 0..n {
        publisher.publish(&topics[i % 8], &payload).unwrap();
    }
    println!(
        "{n_listeners} listeners: {:.1} us per publish",
        t0.elapsed().as_secs_f64() * 1e6 / n as f64
    );
    drop(subs);
}
