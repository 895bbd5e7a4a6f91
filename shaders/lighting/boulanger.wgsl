// Boulanger, Bouatouch & Pattanaik 2008 (`--lighting boulanger`): each leaf
// carries its envelope distances s_max along eight directions (precomputed
// by shared/light/src/boulanger.rs, whose `shade` is the CPU reference of this
// code); light reaching it is attenuated as e^(−τ s) by the foliage in
// between. Direct sky (eq. 6) over the eight directions and one bounce of
// sun light off the neighbouring leaves in closed form (eqs. 11, 23–25),
// added to the tracer's direct sun. Work is in the model's frame, where
// the distances were measured. Appended to render.wgsl.

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

// The model-frame direction `m` in the world: instances are similarities
// (a turn and a uniform scale), so the transpose of `to_model`'s linear
// part points the same way as its inverse.
fn bl_to_world(inst: Instance, m: vec3<f32>) -> vec3<f32> {
    return normalize(inst.to_model[0].xyz * m.x + inst.to_model[1].xyz * m.y + inst.to_model[2].xyz * m.z);
}

// The sun's share of the ground's radiance seen along octant ω (model
// frame) from leaf point s: eq. 6 takes whatever radiance arrives from
// each direction, and below the horizon that is the ground's, which the
// sun lights as well as the sky (`bl_sky` holds the sky's part). The
// ground point the octant's axis meets is tested with one shadow ray, so
// the crown's own shadow and its neighbours' count.
fn ground_sun(s: SurfacePoint, inst: Instance, w: vec3<f32>) -> vec3<f32> {
    let d = bl_to_world(inst, w);
    if frame.has_ground == 0u || d.y > -1.0e-3 || frame.sun_towards.y <= 0.0 {
        return vec3<f32>(0.0);
    }
    let g = s.p + d * (-s.p.y / d.y);
    atomicAdd(&counters.shadow, 1u);
    if in_shadow(vec3<f32>(g.x, frame.epsilon, g.z)) {
        return vec3<f32>(0.0);
    }
    return frame.ground_color * frame.sun_radiance * frame.sun_towards.y;
}

// The light Boulanger et al. add to a leaf or to wood beyond the direct
// sun, which the tracer's shadow ray gives as it does for every method:
// the sky (eq. 6, the ground below the horizon lit by sky and sun) and one
// bounce of sun light off the neighbouring leaves (eqs. 11, 23–25). The
// paper's own sun term (eq. 8, attenuated by eq. 7's interpolated
// thickness) is what a renderer without rays needs;
// `sylva_light::boulanger::shade` still computes it. Wood is Lambertian
// on the side the viewer sees, its neighbours the model's leaves of their
// mean albedo (`shade_wood`); a leaf's neighbours are leaves like it, as
// in the paper.
fn boulanger_light(s: SurfacePoint, view: vec3<f32>) -> vec3<f32> {
    let inst = instances[s.instance];
    let m = models[inst.model];
    // Model-frame normal (as the triangle winds), viewer and sun directions.
    let tri = triangles[s.triangle];
    let a = position(tri.v.x);
    let n = normalize(cross(position(tri.v.y) - a, position(tri.v.z) - a));
    let wo = normalize(to_model_vector(inst, -view));
    let sun = normalize(to_model_vector(inst, frame.sun_towards));
    let wood = s.kind == KIND_WOOD;
    // The neighbours' coefficients (G1), and the wood's normal facing the viewer.
    let c = leaf_coefficients(select(s.albedo, m.leaf_albedo, wood));
    let n_seen = select(n, -n, dot(n, wo) < 0.0);
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
        var f = bl_bsdf(n, wo, c, wj);
        if wood {
            f = s.albedo * max(dot(n_seen, wj), 0.0) / PI;
        }
        sky_light += f * exp(-m.tau * smax[j]) * (frame.bl_sky[j].rgb + ground_sun(s, inst, wj));
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
    return sky_light + indirect;
}
