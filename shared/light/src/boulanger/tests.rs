use super::shade::lo_sample_from;
use super::*;
use std::f32::consts::PI;
use sylva_scene::model::Material;
use sylva_scene::model::{Model, Surface};
use sylva_scene::rng::SplitMix64;
use sylva_scene::trees::{Species, TreeParams, generate};

const COEFFS: [f32; 4] = [0.30, 0.40, 0.20, 0.25];

fn unit(rng: &mut SplitMix64) -> Vec3 {
    let z = 2.0 * rng.next_f64() - 1.0;
    let phi = std::f64::consts::TAU * rng.next_f64();
    let r = (1.0 - z * z).max(0.0).sqrt();
    Vec3::new((r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32)
}

/// Distance from `q` (inside) to the sphere of radius `r` at the origin along unit `d`.
fn chord(q: Vec3, d: Vec3, r: f32) -> f32 {
    let b = q.dot(d);
    -b + (b * b - (q.length_squared() - r * r)).max(0.0).sqrt()
}

fn sphere_env(p: Vec3, r: f32, tau: f32, area: f32) -> LeafEnvelope {
    LeafEnvelope {
        s_max: vec![directions().map(|w| chord(p, w, r))],
        tau,
        leaf_density: 2.0 * tau / area,
        leaf_area: area,
        ..Default::default()
    }
}

#[test]
fn directions_are_diagonals_in_opposite_pairs_and_bins_are_nearest() {
    let d = directions();
    for j in 0..4 {
        assert!((d[j + 4] + d[j]).length() < 1e-6);
        assert!(d[j].y < 0.0);
    }
    assert!(d.iter().all(|w| (w.length() - 1.0).abs() < 1e-6));
    let mut rng = SplitMix64::new(5);
    for _ in 0..10_000 {
        let v = unit(&mut rng);
        let best = (0..N_DIR).max_by(|&a, &b| v.dot(d[a]).total_cmp(&v.dot(d[b]))).unwrap();
        assert_eq!(bin_of(v), best, "{v}");
    }
}

#[test]
fn normal_average_matches_a_numerical_sum_and_g1_assembles_it() {
    let n = 4_000_000;
    for alpha in [0.1f32, 0.7, 1.5, 2.3, 3.0] {
        let (wj, wl) = (Vec3::X, Vec3::new(alpha.cos(), 0.0, alpha.sin()));
        let mut rng = SplitMix64::new(42);
        let (mut refl, mut trans) = (0.0f64, 0.0f64);
        for _ in 0..n {
            let nn = unit(&mut rng);
            refl += (m(nn.dot(wl)) * m(nn.dot(-wj))) as f64;
            trans += (m(nn.dot(wl)) * m(nn.dot(wj))) as f64;
        }
        let (refl, trans) = ((refl / n as f64) as f32, (trans / n as f64) as f32);
        let (er, et) = (normal_average(PI - alpha), normal_average(alpha));
        let (rel_r, rel_t) = ((refl / er - 1.0).abs(), (trans / et - 1.0).abs());
        eprintln!(
            "alpha {alpha}: reflection {refl:.6e} vs {er:.6e} ({:.3} %), transmission {trans:.6e} vs {et:.6e} ({:.3} %)",
            100.0 * rel_r,
            100.0 * rel_t
        );
        assert!(rel_r < 0.02 && rel_t < 0.02, "alpha {alpha}: {rel_r} {rel_t}");
        // Paper's A_vr(α) = (sin α − α cos α)/(6π).
        assert!((er - (alpha.sin() - alpha * alpha.cos()) / (6.0 * PI)).abs() < 1e-6);
    }
    // G1 = ρ 4π/N_dir × [(ρ_rf+ρ_rb) A_vr + (ρ_tf+ρ_tb) A_vt] / π (eqs. 10, 15, 16).
    let env = LeafEnvelope { tau: 1.3, leaf_density: 7.0, leaf_area: 0.37, ..Default::default() };
    let t = sun_terms(&env, Vec3::new(0.3, 1.0, -0.4));
    for j in 0..N_DIR {
        let al = t.sun.dot(directions()[j]).clamp(-1.0, 1.0).acos();
        let [rf, rb, tf, tb] = COEFFS;
        let want = 7.0 * 4.0 * PI / 8.0
            * ((rf + rb) * normal_average(PI - al) + (tf + tb) * normal_average(al))
            / PI;
        assert!(
            (t.g1(j, COEFFS) - want).abs() < 1e-5 * want.abs().max(1e-3),
            "j {j}: {} vs {want}",
            t.g1(j, COEFFS)
        );
    }
}

fn test_points() -> [Vec3; 3] {
    [Vec3::ZERO, Vec3::new(0.4, -0.3, 0.2), Vec3::new(0.85, 0.3, -0.1)]
}

fn test_suns() -> [Vec3; 4] {
    [
        Vec3::new(0.3, 1.0, 0.2),
        Vec3::new(-1.0, 0.2, 0.5),
        directions()[4],
        Vec3::new(0.1, -0.2, 1.0),
    ]
}

#[test]
fn closed_form_lo_sample_matches_the_slice_sum() {
    let (r, tau, area, e_sun) = (1.0, 2.0, 1e-4, 3.0);
    let dirs = directions();
    let mut worst = 0.0f32;
    let mut worst_true = 0.0f32;
    for p in test_points() {
        let env = sphere_env(p, r, tau, area);
        let s = env.s_max[0];
        for sun in test_suns() {
            let t = sun_terms(&env, sun);
            for j in 0..N_DIR {
                let closed = lo_sample(&t, &s, j, COEFFS, e_sun);
                let ns = 20_000;
                let ds = s[j] / ns as f32;
                let (mut sum, mut sum_true) = (0.0f64, 0.0f64);
                for i in 1..=ns {
                    let si = i as f32 * ds;
                    // Eq. 22: the model's sun distance from P + s ω_j.
                    let s22: f32 =
                        (0..N_DIR).map(|k| t.weights[k] * (s[k] - dirs[j].dot(dirs[k]) * si)).sum();
                    sum += ((-tau * si).exp() * (-tau * s22).exp() * e_sun * ds) as f64;
                    // The sphere's exact sun distance, for information.
                    let exact = chord(p + dirs[j] * si, t.sun, r);
                    sum_true += ((-tau * si).exp() * (-tau * exact).exp() * e_sun * ds) as f64;
                }
                let slice = t.g1(j, COEFFS) * sum as f32;
                let rel = (closed / slice - 1.0).abs();
                worst = worst.max(rel);
                worst_true =
                    worst_true.max((closed / (t.g1(j, COEFFS) * sum_true as f32) - 1.0).abs());
                assert!(rel < 0.02, "P {p} sun {sun} j {j}: closed {closed} slices {slice}");
                assert!(closed.is_finite() && closed >= 0.0);
            }
        }
    }
    eprintln!(
        "Lo_sample closed form vs eq. 17 slice sum: worst {:.4} %; vs exact sphere irradiance: worst {:.1} %",
        100.0 * worst,
        100.0 * worst_true
    );
}

/// Lo_ind as an explicit sum over random leaves around `p`, and the
/// closed form, both leaving out the ball of radius `r0` around P.
/// `model_geometry`: leaves fill the model's envelope (octant sectors
/// of radius s_max(P, ω_j)), directions snap to ω_j and the neighbours'
/// sun distance is eq. 22: this isolates the normal averaging, leaf
/// counting and integration. Otherwise: leaves fill the true sphere,
/// with exact directions and exact sun distances.
fn lo_ind_explicit(p: Vec3, sun: Vec3, model_geometry: bool, seed: u64) -> (f32, f32) {
    let (r, tau, density, e_sun, r0) = (1.0f32, 2.0f32, 2.0e5f32, 1.0f32, 0.08f32);
    let area = 2.0 * tau / density;
    let env = sphere_env(p, r, tau, area);
    let s = env.s_max[0];
    let t = sun_terms(&env, sun);
    let dirs = directions();
    let (normal, to_eye) =
        (Vec3::new(0.2, 0.9, -0.3).normalize(), Vec3::new(0.5, 0.4, 0.7).normalize());
    let closed: f32 = area
        * (0..N_DIR)
            .map(|j| {
                bsdf(normal, to_eye, COEFFS, dirs[j]) * lo_sample_from(&t, &s, j, COEFFS, e_sun, r0)
            })
            .sum::<f32>();
    // Leaves uniform in a ball around `centre` of radius `radius`.
    let (centre, radius) =
        if model_geometry { (p, s.iter().cloned().fold(0.0, f32::max)) } else { (Vec3::ZERO, r) };
    let count = (density * 4.0 / 3.0 * PI * radius.powi(3)).round() as usize;
    let mut rng = SplitMix64::new(seed);
    let mut sum = 0.0f64;
    for _ in 0..count {
        let q = centre + unit(&mut rng) * radius * (rng.next_f64() as f32).cbrt();
        let n_leaf = unit(&mut rng);
        let d = q - p;
        let dist = d.length();
        if dist < r0 {
            continue;
        }
        let j = bin_of(d);
        let (w, sun_dist) = if model_geometry {
            if dist > s[j] {
                continue;
            }
            (
                dirs[j],
                (0..N_DIR)
                    .map(|k| t.weights[k] * (s[k] - dirs[j].dot(dirs[k]) * dist))
                    .sum::<f32>(),
            )
        } else {
            (d / dist, chord(q, t.sun, r))
        };
        // Eq. 9: F(P, ω_o, PP') Lo_sun(P', −PP') V |N'·PP'| / |PP'|².
        let lo_sun = bsdf(n_leaf, -w, COEFFS, t.sun) * (-tau * sun_dist).exp() * e_sun;
        sum +=
            (bsdf(normal, to_eye, COEFFS, w) * lo_sun * (-tau * dist).exp() * n_leaf.dot(w).abs()
                / (dist * dist)) as f64;
    }
    (closed, area * sum as f32)
}

#[test]
fn closed_form_lo_ind_matches_a_sum_over_random_leaves() {
    let mut worst = 0.0f32;
    for (k, (p, sun)) in [
        (Vec3::ZERO, Vec3::new(0.3, 1.0, 0.2)),
        (Vec3::new(0.4, -0.3, 0.2), Vec3::new(-1.0, 0.2, 0.5)),
        (Vec3::new(0.1, 0.5, 0.3), Vec3::new(0.2, 1.0, -0.6)),
    ]
    .into_iter()
    .enumerate()
    {
        let (closed, explicit) = lo_ind_explicit(p, sun, true, 100 + k as u64);
        let rel = (closed / explicit - 1.0).abs();
        worst = worst.max(rel);
        let (closed_t, explicit_t) = lo_ind_explicit(p, sun, false, 200 + k as u64);
        eprintln!(
            "P {p} sun {sun}: model geometry closed {closed:.5e} explicit {explicit:.5e} ({:.2} %); true sphere closed {closed_t:.5e} explicit {explicit_t:.5e} ({:+.1} %)",
            100.0 * rel,
            100.0 * (closed_t / explicit_t - 1.0)
        );
        assert!(rel < 0.02, "P {p} sun {sun}: closed {closed} explicit {explicit}");
    }
    eprintln!("worst model-geometry error {:.2} %", 100.0 * worst);
}

#[test]
fn precompute_on_a_generated_tree() {
    let model =
        generate(&TreeParams { species: Species::RedMaple, triangles: Some(20_000), seed: 1 })
            .unwrap();
    let env = precompute(&model);
    eprintln!(
        "tree: {} leaves, tau {}, density {}, area {}, {:.1} ms",
        env.leaves, env.tau, env.leaf_density, env.leaf_area, env.precompute_ms
    );
    assert!(env.tau > 0.0 && env.tau.is_finite());
    assert_eq!(env.s_max.len(), model.triangle_count());
    assert!(env.s_max.iter().flatten().all(|s| s.is_finite() && *s >= 0.0));
    let leaf_tris: Vec<usize> =
        (0..model.triangle_count()).filter(|&t| model.surface(t) == Surface::Leaf).collect();
    // Wood is measured too: the branches inside the crown see leaves.
    let wood: Vec<usize> =
        (0..model.triangle_count()).filter(|&t| model.surface(t) == Surface::Wood).collect();
    let shaded = wood.iter().filter(|&&t| env.s_max[t].iter().any(|&s| s > 0.0)).count();
    assert!(shaded * 2 > wood.len(), "{shaded} of {} wood triangles see foliage", wood.len());
    // The leaves' mean albedo is a leaf's: green above red above blue, all in (0, 1).
    let [r, g, b] = env.leaf_albedo;
    assert!(0.0 < b && b < r && r < g && g < 1.0, "{:?}", env.leaf_albedo);
    // Quads are cards: both halves share their values.
    assert!(env.leaves * 2 <= leaf_tris.len() + 1);
    assert_eq!(env.s_max[leaf_tris[0]], env.s_max[leaf_tris[1]]);
    let centre_of = |t: usize| model.triangle(t).iter().sum::<Vec3>() / 3.0;
    // Each leaf sees more foliage towards the octant holding the most
    // leaves within 4 m than towards the one holding the fewest.
    let cards: Vec<(usize, Vec3)> =
        leaf_tris.iter().step_by(2).map(|&t| (t, centre_of(t))).collect();
    let (mut more, mut ratio_in, mut ratio_out) = (0usize, 0.0f64, 0.0f64);
    for &(t, p) in &cards {
        let mut count = [0usize; N_DIR];
        for &(u, q) in &cards {
            let d = q - p;
            if u != t && d.length_squared() < 16.0 {
                count[bin_of(d)] += 1;
            }
        }
        let most = (0..N_DIR).max_by_key(|&j| count[j]).unwrap();
        let fewest = (0..N_DIR).min_by_key(|&j| count[j]).unwrap();
        more += (env.s_max[t][most] > env.s_max[t][fewest]) as usize;
        ratio_in += env.s_max[t][most] as f64;
        ratio_out += env.s_max[t][fewest] as f64;
    }
    let frac = more as f32 / cards.len() as f32;
    eprintln!(
        "tree: s_max towards the fullest octant > towards the emptiest for {:.1} % of leaves; means {:.3} vs {:.3}",
        100.0 * frac,
        ratio_in / cards.len() as f64,
        ratio_out / cards.len() as f64
    );
    assert!(frac > 0.8 && ratio_in > 2.0 * ratio_out, "{frac} {ratio_in} {ratio_out}");
    // The shading terms are finite on a real tree.
    let t = sun_terms(&env, Vec3::Y);
    let sky = [0.0; N_DIR];
    let light = ChannelLight { env: &env, terms: &t, e_sun: 1.0, sky: &sky };
    let (_, sun_in, ind_in) = shade(&light, leaf_tris[0], Vec3::Y, Vec3::Y, COEFFS);
    assert!(sun_in.is_finite() && ind_in.is_finite() && ind_in >= 0.0);
}

#[test]
fn precompute_on_a_sphere_of_cards_recovers_density_and_thickness() {
    // 20,000 random square cards uniformly in a unit sphere.
    let mut model = Model::default();
    let leaf = model.add_material(Material::plain("leaf", Surface::Leaf, [0.2, 0.6, 0.1]));
    let mut rng = SplitMix64::new(7);
    let (n, side) = (20_000usize, 0.02f32);
    for _ in 0..n {
        let c = unit(&mut rng) * (rng.next_f64() as f32).cbrt();
        let nn = unit(&mut rng);
        let u = nn.any_orthonormal_vector() * side * 0.5;
        let v = nn.cross(u);
        model.push_quad([c - u - v, c + u - v, c + u + v, c - u + v], leaf);
    }
    let env = precompute(&model);
    let true_tau = 0.5 * n as f32 / (4.0 / 3.0 * PI) * side * side;
    eprintln!("sphere: tau {} (true {true_tau}), {:.1} ms", env.tau, env.precompute_ms);
    assert_eq!(env.leaves, n);
    assert_eq!(env.leaf_albedo, [0.2, 0.6, 0.1], "one untextured material: its colour");
    assert!((env.tau / true_tau - 1.0).abs() < 0.35, "tau {} true {true_tau}", env.tau);
    // Near the centre, τ s_max ≈ τ R in every direction.
    let mut depth = Vec::new();
    for t in (0..model.triangle_count()).step_by(2) {
        let c = model.triangle(t).iter().sum::<Vec3>() / 3.0;
        if c.length() < 0.25 {
            depth.extend(env.s_max[t].iter().map(|s| s * env.tau));
        }
    }
    let mean = depth.iter().sum::<f32>() / depth.len() as f32;
    eprintln!("centre leaves: mean optical depth {mean}, true about {true_tau}");
    assert!((mean / true_tau - 1.0).abs() < 0.3, "mean depth {mean} true {true_tau}");
    // Leaves at the surface near a diagonal see (almost) nothing outwards:
    // every direction of that octant leaves the sphere at once.
    let mut out = Vec::new();
    for t in (0..model.triangle_count()).step_by(2) {
        let c = model.triangle(t).iter().sum::<Vec3>() / 3.0;
        let j = bin_of(c);
        if c.length() > 0.93 && c.normalize().dot(directions()[j]) > 25f32.to_radians().cos() {
            out.push(env.s_max[t][j] * env.tau);
        }
    }
    let out_mean = out.iter().sum::<f32>() / out.len() as f32;
    eprintln!("{} surface leaves: mean optical depth outwards {out_mean}", out.len());
    assert!(out.len() > 20 && out_mean < 0.3 * mean, "{out_mean} vs {mean}");
}

#[test]
fn sky_average_and_ground_reflection() {
    let sky = |d: Vec3| [1.0 + d.y, 2.0, 0.5 * d.x.max(0.0)];
    let l = sky_radiance_per_direction(sky, [0.5, 0.25, 0.1]);
    let d = directions();
    for j in 4..8 {
        // Mean of y over an upper octant is 1/2.
        assert!((l[j][0] - 1.5).abs() < 1e-3 && (l[j][1] - 2.0).abs() < 1e-5, "{:?}", l[j]);
        if d[j].x < 0.0 {
            assert_eq!(l[j][2], 0.0);
        }
    }
    // Ground: albedo × (1/π)∫(1 + cos θ) cos θ dω = albedo × (1 + 2/3).
    for lj in &l[..4] {
        assert!(
            (lj[0] - 0.5 * (1.0 + 2.0 / 3.0)).abs() < 2e-3 && (lj[1] - 0.25 * 2.0).abs() < 1e-4,
            "{lj:?}"
        );
    }
}

#[test]
fn shade_terms_match_the_equations_for_a_single_direction() {
    let env = sphere_env(Vec3::ZERO, 1.0, 1.5, 1e-3);
    let t = sun_terms(&env, Vec3::Y);
    let mut sky = [0.0; N_DIR];
    sky[4] = 2.0;
    let n = directions()[4];
    let light = ChannelLight { env: &env, terms: &t, e_sun: 3.0, sky: &sky };
    let (lo_sky, lo_sun, lo_ind) = shade(&light, 0, n, n, COEFFS);
    let want_sky = 4.0 * PI / 8.0 * COEFFS[0] / PI * (-1.5f32).exp() * 2.0;
    assert!((lo_sky - want_sky).abs() < 1e-5, "{lo_sky} {want_sky}");
    let want_sun = COEFFS[0] / PI * XI * (-1.5f32).exp() * 3.0;
    assert!((lo_sun - want_sun).abs() < 1e-5, "{lo_sun} {want_sun}");
    assert!(lo_ind > 0.0 && lo_ind.is_finite());
}
