use glam::Vec3;
use pc_artifact::octree::OctreeFile;
use pc_tree::accel::Accel;
use pc_tree::{Ray, TraversalStats};
use rand::{Rng, SeedableRng};

fn main() {
    let path = std::env::args().nth(1).unwrap();
    let min_len: f32 = std::env::args()
        .nth(2)
        .map(|s| s.parse().unwrap())
        .unwrap_or(0.3);
    let f = OctreeFile::open(&path).unwrap();
    let view = f.view();
    let accel = Accel::new(&view);
    let n = view.splats.len();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(1);
    let mut st = TraversalStats::default();
    let (mut cast, mut blocked) = (0u64, 0u64);
    let mut near_a_same = 0u64;
    let mut near_b_same = 0u64;
    let mut mid = 0u64;
    let mut hist = [0u64; 12];
    let mut hh_hist = [0u64; 9];
    while cast < 200_000 {
        let ia = rng.gen_range(0..n);
        let ib = rng.gen_range(0..n);
        let (si, sj) = (&view.splats[ia], &view.splats[ib]);
        let (xa, na, ra) = (Vec3::from(si.position), Vec3::from(si.normal), si.radius);
        let (xb, nb, rb) = (Vec3::from(sj.position), Vec3::from(sj.normal), sj.radius);
        let d = xb - xa;
        let len = d.length();
        if len < min_len {
            continue;
        }
        let dir = d / len;
        if na.dot(dir) <= 0.0 || nb.dot(-dir) <= 0.0 {
            continue;
        }
        let ray = Ray {
            origin: xa,
            dir,
            t_min: 0.5 * ra,
            t_max: len - 0.5 * rb,
        };
        cast += 1;
        if let Some(h) = accel.intersect(&view, &ray, &mut st) {
            blocked += 1;
            let hn = Vec3::from(view.splats[h.splat as usize].normal);
            let ta = h.t / ra;
            let tb = (len - h.t) / rb;
            if ta < 10.0 && hn.dot(na) > 0.5 {
                near_a_same += 1;
            } else if tb < 10.0 && hn.dot(nb) > 0.5 {
                near_b_same += 1;
            } else {
                mid += 1;
            }
            let hp = xa + dir * h.t;
            let (ha, hb) = ((hp - xa).dot(na).abs() / ra, (hp - xb).dot(nb).abs() / rb);
            let same_a = hn.dot(na) > 0.5;
            let same_b = hn.dot(nb) > 0.5;
            let hh = if same_a && (!same_b || ha < hb) {
                ha
            } else if same_b {
                hb
            } else {
                99.0
            };
            let hbin = if hh < 0.125 {
                0
            } else if hh >= 16.0 {
                8
            } else {
                ((hh * 8.0).log2() as usize + 1).min(8)
            };
            hh_hist[hbin] += 1;
            let m = ta.min(tb);
            let bin = if m < 1.0 {
                0
            } else {
                (m.log2() as usize + 1).min(11)
            };
            hist[bin] += 1;
        }
    }
    println!(
        "cast {cast} blocked {blocked} ({:.1} %)",
        100.0 * blocked as f64 / cast as f64
    );
    println!("blocked within 10 radii of an end on a same-facing splat: at A {near_a_same}, at B {near_b_same}; elsewhere {mid}");
    println!("height of the hit above the same-facing end's plane, in its radii: <1/8, 1/8-1/4, 1/4-1/2, 1/2-1, 1-2, 2-4, 4-8, 8-16, >16 or other: {hh_hist:?}");
    println!("hist of min(t/ra, (len-t)/rb): <1, 1-2, 2-4, ...: {hist:?}");
}
