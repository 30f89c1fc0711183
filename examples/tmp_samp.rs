use latentbki::{Codebook, Sampler, SamplingMode, VoxelStats};
fn main() {
    let mode = std::env::args().nth(1).unwrap_or_default();
    let mut s = 17u64;
    let mut r = move || { s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407); (s >> 40) as f32 / (1u64 << 24) as f32 };
    let vs: Vec<VoxelStats<64>> = (0..10000).map(|_| { let l = 2.5 + 60.0 * r() * r(); VoxelStats { lambda: l, mean: core::array::from_fn(|_| r() - 0.5), psi: core::array::from_fn(|_| 1.0 + 0.2 * l * r()) } }).collect();
    let e: Vec<[f32; 64]> = (0..50).map(|_| core::array::from_fn(|_| r() - 0.5)).collect();
    let cb = Codebook::<64, 50>::from_embeddings(&e).unwrap();
    let mut sm = Sampler::<64>::new(3);
    let m = if mode == "sound" { SamplingMode::Sound } else { SamplingMode::Authors };
    let mut acc = 0.0;
    let t = std::time::Instant::now();
    for _ in 0..5 { for v in &vs { let (b, _) = cb.argmax(&v.mean).unwrap(); acc += sm.score_variance(m, v, &cb, b, 30).unwrap_or(0.0); } }
    println!("{acc} {:?}/iter", t.elapsed() / 5);
}
