use latentbki::Sampler;
fn main() {
    let mut s = Sampler::<4>::new(1);
    let mut buf = vec![0f32; 1 << 20];
    let t = std::time::Instant::now();
    let mut acc = 0.0;
    for _ in 0..20 { s.fill_normal(&mut buf); acc += buf[5]; }
    println!("normal {:.2} ns {acc}", t.elapsed().as_nanos() as f64 / (20 << 20) as f64);
    let t = std::time::Instant::now();
    for _ in 0..20 { s.fill_student_t(5.0, &mut buf); acc += buf[5]; }
    println!("t {:.2} ns {acc}", t.elapsed().as_nanos() as f64 / (20 << 20) as f64);
    let t = std::time::Instant::now();
    for _ in 0..20 { s.fill_chi_squared(5.0, &mut buf); acc += buf[5]; }
    println!("chi2 {:.2} ns {acc}", t.elapsed().as_nanos() as f64 / (20 << 20) as f64);
}
