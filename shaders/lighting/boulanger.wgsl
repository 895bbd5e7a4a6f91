// Boulanger, Bouatouch & Pattanaik 2008 (`--lighting boulanger`): each leaf
// carries its envelope distances s_max along eight directions (precomputed
// by shared/light/src/boulanger.rs, whose `shade` is the CPU reference of this
// code); light reaching it is attenuated as e^(−τ s) by the foliage in
// between. Direct sky (eq. 6) over the eight directions, direct sun with
// the cosine-lobe s_max of eq. 7 (eq. 8), and one bounce of sun light off
// the neighbouring leaves in closed form (eqs. 11, 23–25). Work is in the
// model's frame, where the distances were measured. Appended to render.wgsl.

const BL_XI: f32 = 0.57735027;
const BL_N: u32 = 8u;

// ω_j: the cube diagonals, the first four below the horizon, ω_{j+4} = −ω_j.
fn bl_direction(j: u32) -> vec3<f32> {
    let low = array<vec3<f32>, 4>(vec3<f32>(-BL_XI, -BL_XI, -BL_XI), vec3<f32>(BL_XI, -BL_XI, -BL_XI), vec3<f32>(-BL_XI, -BL_XI, BL_XI), vec3<f32>(BL_XI, -BL_XI, BL_XI));
    if j < 4u {
        return low[j];
    }
    return -low[j - 4u];
}

// The cosine-weighted leaf BSDF F(P, ω_o, ω) of eq. 4, per colour:
// c = (ρ_rf, ρ_rb, ρ_tf, ρ_tb).
fn bl_bsdf(n: vec3<f32>, wo: vec3<f32>, c: array<vec3<f32>, 4>, w: vec3<f32>) -> vec3<f32> {
    let cw = dot(n, w);
    if dot(n, wo) >= 0.0 {
        return (c[0] * max(cw, 0.0) + c[3] * max(-cw, 0.0)) / PI;
    }
    return (c[2] * max(cw, 0.0) + c[1] * max(-cw, 0.0)) / PI;
}

// Outgoing radiance of a leaf: sky + sun + indirect sun (eq. 2).
fn boulanger_leaf(s: SurfacePoint, view: vec3<f32>) -> vec3<f32> {
    let inst = instances[s.instance];
    let m = models[inst.model];
    // Model-frame normal (as the triangle winds), viewer and sun directions.
    let tri = triangles[s.triangle];
    let a = position(tri.v.x);
    let n = normalize(cross(position(tri.v.y) - a, position(tri.v.z) - a));
    let wo = normalize(to_model_vector(inst, -view));
    let sun = normalize(to_model_vector(inst, frame.sun_towards));
    let c = leaf_coefficients(s.albedo);
    var smax: array<f32, 8>;
    var mw: array<f32, 8>;
    var msum = 0.0;
    for (var j = 0u; j < BL_N; j++) {
        smax[j] = envelope[8u * s.triangle + j];
        mw[j] = max(dot(sun, bl_direction(j)), 0.0);
        msum += mw[j];
    }
    // τ s_max(P, ω_l), eq. 7 (= G2 Σ M s_max).
    var sun_depth = 0.0;
    for (var j = 0u; j < BL_N; j++) {
        sun_depth += mw[j] * smax[j];
    }
    sun_depth *= m.tau / msum;
    // The sun's irradiance: a surface facing it reflects ρ E cosθ, so E = π·sun_radiance.
    let e_sun = PI * frame.sun_radiance;
    let rho_bar = c[0] + c[1] + c[2] + c[3];
    let scale = 2.0 * m.leaf_density / (3.0 * PI * f32(BL_N));
    var sky_light = vec3<f32>(0.0);
    var indirect = vec3<f32>(0.0);
    for (var j = 0u; j < BL_N; j++) {
        let wj = bl_direction(j);
        let f = bl_bsdf(n, wo, c, wj);
        sky_light += f * exp(-m.tau * smax[j]) * frame.bl_sky[j].rgb;
        // G1 (eq. 18), G3 (eq. 25) and Lo_sample (eq. 23).
        let cos_a = clamp(dot(sun, wj), -1.0, 1.0);
        let alpha = acos(cos_a);
        let g1 = rho_bar * (scale * (sin(alpha) - alpha * cos_a)) + (c[2] + c[3]) * (scale * PI * cos_a);
        var cj = 0.0;
        for (var k = 0u; k < BL_N; k++) {
            cj += mw[k] * dot(wj, bl_direction(k));
        }
        let g3 = max(m.tau * (1.0 - cj / msum), 0.0);
        var integral = smax[j];
        if g3 > 0.0 {
            integral = (1.0 - exp(-g3 * smax[j])) / g3;
        }
        indirect += f * g1 * e_sun * exp(-sun_depth) * integral;
    }
    sky_light *= 4.0 * PI / f32(BL_N);
    indirect *= m.leaf_area;
    let sun_light = bl_bsdf(n, wo, c, sun) * exp(-sun_depth) * e_sun;
    return sky_light + sun_light + indirect;
}
