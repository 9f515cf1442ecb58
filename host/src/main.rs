use rand::SeedableRng;
use rand_distr::Distribution;
fn main(){
    let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let n = rand_distr::Normal::new(0.0f64, 1.0).unwrap();
    let u = rand_distr::Uniform::new(0.0f64, 1.0).unwrap();
    println!("{} {}", n.sample(&mut r), u.sample(&mut r));
    use rand::RngExt;
    let x: f64 = r.random();
    let k = r.random_range(0..10usize);
    println!("{x} {k}");
}
