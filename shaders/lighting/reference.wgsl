// The reference integrator (`--lighting reference`): a path tracer on the
// same triangles, traversal and textures as the direct methods. Leaves
// reflect and transmit Lambertianly per side (Boulanger et al.'s ρ_rf, ρ_rb,
// ρ_tf, ρ_tb as multipliers of the texture colour, shared/scene/src/leaf/mod.rs); wood
// and the ground are Lambertian; the sky is the same gradient; clouds are a
// heterogeneous medium sampled by delta tracking with the Henyey–Greenstein
// phase function, their transmittance towards the sun by ratio tracking.
// The sun is sampled at every vertex (next-event estimation), so with no
// bounce the reference equals `local`. Paths end by Russian roulette after
// three bounces, or at `frame.max_bounces`.
//
// The gathers (`gather`, `gather-ambient`) are these paths, truncated: at
// the surface `frame.gather_bounces` bounces from the camera a path takes
// its sun as every vertex does, adds what the lattice (or the matched
// constant) says reaches that surface besides the sun, and ends. Appended
// to render.wgsl, which calls reference_sample.

const PI: f32 = 3.14159265;

var<private> rng_state: u32;

fn rand() -> f32 {
    rng_state = pcg(rng_state);
    return f32(rng_state >> 8u) / 16777216.0;
}

// An orthonormal frame around unit `n` (Duff et al. 2017).
fn frame_around(n: vec3<f32>) -> mat3x3<f32> {
    let s = select(-1.0, 1.0, n.z >= 0.0);
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    let t = vec3<f32>(1.0 + s * n.x * n.x * a, s * b, -s * n.x);
    let u = vec3<f32>(b, s + n.y * n.y * a, -n.y);
    return mat3x3<f32>(t, u, n);
}

// A cosine-distributed direction around `n`.
fn cosine_direction(n: vec3<f32>) -> vec3<f32> {
    let u1 = rand();
    let u2 = rand();
    let r = sqrt(u1);
    let phi = 2.0 * PI * u2;
    return normalize(frame_around(n) * vec3<f32>(r * cos(phi), r * sin(phi), sqrt(max(0.0, 1.0 - u1))));
}

// Henyey–Greenstein phase function of the angle between the propagation
// directions before and after scattering.
fn hg_phase(cos_theta: f32, g: f32) -> f32 {
    let d = 1.0 + g * g - 2.0 * g * cos_theta;
    return (1.0 - g * g) / (4.0 * PI * d * sqrt(d));
}

// A direction scattered from propagation direction `d`, by HG inversion.
fn hg_direction(d: vec3<f32>, g: f32) -> vec3<f32> {
    let u1 = rand();
    let u2 = rand();
    var cos_theta: f32;
    if abs(g) < 1e-3 {
        cos_theta = 1.0 - 2.0 * u1;
    } else {
        let q = (1.0 - g * g) / (1.0 - g + 2.0 * g * u1);
        cos_theta = clamp((1.0 + g * g - q * q) / (2.0 * g), -1.0, 1.0);
    }
    let sin_theta = sqrt(max(0.0, 1.0 - cos_theta * cos_theta));
    let phi = 2.0 * PI * u2;
    return normalize(frame_around(d) * vec3<f32>(sin_theta * cos(phi), sin_theta * sin(phi), cos_theta));
}

// Density (0..1) of cloud `c` at world point p.
fn cloud_density(c: Cloud, p: vec3<f32>) -> f32 {
    let cell = c.size / f32(c.n);
    return cloud_sample(c, 0u, (p - c.min) / cell - 0.5);
}

// The part of [0, t_max) of a ray inside cloud `c` (empty: x > y).
fn cloud_span(c: Cloud, ray: Ray, t_max: f32) -> vec2<f32> {
    if c.n == 0u {
        return vec2<f32>(1.0, 0.0);
    }
    return clip_box(c.min, c.min + vec3<f32>(c.size), ray, 0.0, t_max);
}

// The first real collision with a cloud before `t_max` by delta tracking
// (density ≤ 1, so the majorant is the cloud's extinction): (t, cloud) or
// t < 0 when the ray gets through. Clouds do not overlap, so sampling each
// span on its own and keeping the nearest collision is exact.
fn cloud_collision(ray: Ray, t_max: f32) -> vec2<f32> {
    var best = vec2<f32>(-1.0, 0.0);
    if !HAS_CLOUDS {
        return best;
    }
    let len = length(ray.dir);
    for (var i = 0u; i < arrayLength(&clouds); i++) {
        let c = clouds[i];
        let span = cloud_span(c, ray, t_max);
        if span.x > span.y {
            continue;
        }
        let majorant = c.extinction * len;
        var t = span.x;
        for (var k = 0u; k < 4096u; k++) {
            t -= log(1.0 - rand()) / majorant;
            if t >= span.y {
                break;
            }
            if rand() < cloud_density(c, ray.origin + ray.dir * t) {
                if best.x < 0.0 || t < best.x {
                    best = vec2<f32>(t, f32(i));
                }
                break;
            }
        }
    }
    return best;
}

// Transmittance of the clouds along [0, t_max) of a ray, by ratio tracking.
fn cloud_transmittance(ray: Ray, t_max: f32) -> f32 {
    var tr = 1.0;
    if !HAS_CLOUDS {
        return tr;
    }
    let len = length(ray.dir);
    for (var i = 0u; i < arrayLength(&clouds); i++) {
        let c = clouds[i];
        let span = cloud_span(c, ray, t_max);
        if span.x > span.y {
            continue;
        }
        let majorant = c.extinction * len;
        var t = span.x;
        for (var k = 0u; k < 4096u; k++) {
            t -= log(1.0 - rand()) / majorant;
            if t >= span.y || tr < 1e-4 {
                break;
            }
            tr *= 1.0 - cloud_density(c, ray.origin + ray.dir * t);
        }
    }
    return tr;
}

// How much of the sun reaches p: 0 behind geometry, else what the clouds let through.
fn sun_visibility(p: vec3<f32>) -> f32 {
    if frame.sun_towards.y <= 0.0 && frame.has_ground == 1u {
        return 0.0;
    }
    atomicAdd(&counters.shadow, 1u);
    if in_shadow(p) {
        return 0.0;
    }
    return cloud_transmittance(make_ray(p, frame.sun_towards), 3.0e38);
}

// A leaf's reflectance and transmittance seen from the side `wo` leaves.
fn leaf_optics(n: vec3<f32>, wo: vec3<f32>, albedo: vec3<f32>) -> array<vec3<f32>, 2> {
    let c = leaf_coefficients(albedo);
    if dot(n, wo) >= 0.0 {
        // Seen from the front: light from the front is reflected (ρ_rf),
        // light entering the back face comes through (ρ_tb).
        return array<vec3<f32>, 2>(c[0], c[3]);
    }
    return array<vec3<f32>, 2>(c[1], c[2]);
}

fn mean3(v: vec3<f32>) -> f32 {
    return (v.x + v.y + v.z) / 3.0;
}

// Whether this frame is a gather (the reference's paths, truncated).
fn gathering() -> bool {
    return frame.lighting == LIGHTING_GATHER || frame.lighting == LIGHTING_GATHER_AMBIENT;
}

// What reaches surface `s` (n on the arriving ray's side) besides the
// direct sun, as the radiance it sends back along that ray: the light of
// the second and later bounces, from the LB (`gather`) or the constant
// matched to it (`gather-ambient`), read as every direct method reads it
// (docs/lighting.md, "A final gather over the LB").
fn gather_far_end(s: SurfacePoint, n: vec3<f32>) -> vec3<f32> {
    if s.kind == KIND_GROUND {
        return s.albedo * ground_indirect(s.p);
    }
    if frame.lighting == LIGHTING_GATHER_AMBIENT {
        return diffuse_albedo(s, n) * frame.ambient;
    }
    let inst = instances[s.instance];
    return diffuse_albedo(s, n) * lb_indirect(inst, to_model_point(inst, s.p));
}

// Seeds the random numbers of sample `s` of pixel (x, y).
fn seed_path(x: u32, y: u32, s: u32) {
    rng_state = pcg(x ^ pcg(y ^ pcg(s ^ pcg(frame.seed ^ 0x5bd1e995u))));
}

// Path `s` through pixel (x, y): its radiance (alpha 1 where its first
// surface is a model), and what `local` shows along the same camera ray
// (the sky, or the first surface's direct sun and the open ground's sky
// term), so the reference's indirect light is the difference without
// another sampling's edge aliasing.
//
// One path per invocation: on lavapipe (Mesa 22.3) a loop over samples
// around the loop over bounces silently dropped samples of lanes whose paths
// ended early (up to 20 % of the samples of a forest frame).
//
// With PASSES, two more: the camera ray's normal (its albedo is the third
// image's), and its depth and ids (`guides` in render.wgsl), from the
// first surface the path meets anyway.
fn reference_sample(x: u32, y: u32, s: u32) -> array<vec4<f32>, 7> {
    var depth = 0u;
    var ray = camera_ray(x, y, s);
    seed_path(x, y, s);
    var beta = vec3<f32>(1.0);
    var light = vec3<f32>(0.0);
    var coverage = 0.0;
    var first_light = vec3<f32>(0.0);
    // The first surface's distance and the albedo a diffuse field sees
    // there: the gathers' filter demodulates and edge-stops with them.
    var first_depth = 0.0;
    var first_albedo = vec3<f32>(0.0);
    var first_surface_hit = 0.0;
    // The passes' split of the first event (docs/passes.md): the sun's
    // light off a first surface, or the sky seen directly (w = 1).
    var first_split = vec4<f32>(0.0);
    var first_normal = vec4<f32>(0.0);
    var first_ids = vec4<f32>(0.0);
    var alive = true;
    loop {
        if !alive || depth > frame.max_bounces {
            break;
        }
        let surf = first_surface(ray);
        if PASSES && depth == 0u {
            let g = guides(ray, surf);
            first_normal = g[1];
            first_ids = vec4<f32>(g[0].w, g[2].x, g[2].y, 0.0);
        }
        var hit = vec2<f32>(-1.0, 0.0);
        if HAS_CLOUDS {
            hit = cloud_collision(ray, surf.t);
        }
        let d = normalize(ray.dir);
        // The sun's next-event estimate: where it is tested from and what it
        // brings if visible. One visibility test per segment, so the
        // traversal is compiled in two places only (here and first_surface).
        var sun_from = vec3<f32>(0.0);
        var sun_light = vec3<f32>(0.0);
        if HAS_CLOUDS && hit.x >= 0.0 {
            // Scattered inside a cloud: the sun through the phase function,
            // then on in a phase-sampled direction.
            let c = clouds[u32(hit.y)];
            let p = ray.origin + ray.dir * hit.x;
            beta *= c.albedo;
            sun_from = p;
            // A directional sun of radiance-scale E lights a surface with ρE cosθ, i.e. irradiance πE.
            sun_light = beta * hg_phase(dot(d, frame.sun_towards), c.g) * PI * frame.sun_radiance;
            ray = make_ray(p, hg_direction(d, c.g));
        } else if surf.kind == KIND_SKY {
            light += beta * sky(d);
            if depth == 0u {
                first_split = vec4<f32>(sky(d), 1.0);
            }
            alive = false;
        } else {
            if depth == 0u && surf.kind != KIND_GROUND {
                coverage = 1.0;
            }
            let wo = -d;
            // The normal on the viewer's side.
            let n = select(surf.n, -surf.n, dot(surf.n, wo) < 0.0);
            var reflect_c = surf.albedo;
            var transmit_c = vec3<f32>(0.0);
            if surf.kind == KIND_LEAF {
                let o = leaf_optics(surf.n, wo, surf.albedo);
                reflect_c = o[0];
                transmit_c = o[1];
            }
            if depth == 0u {
                first_depth = surf.t;
                first_albedo = reflect_c + transmit_c;
                first_surface_hit = 1.0;
            }
            // The sun: reflected when it lights the viewer's side, transmitted when the other.
            let cos_sun = dot(n, frame.sun_towards);
            if cos_sun > 0.0 {
                sun_from = surf.p + n * frame.epsilon;
                sun_light = beta * frame.sun_radiance * reflect_c * cos_sun;
            } else if cos_sun < 0.0 && surf.kind == KIND_LEAF {
                sun_from = surf.p - n * frame.epsilon;
                sun_light = beta * frame.sun_radiance * transmit_c * (-cos_sun);
            }
            if depth == 0u && surf.kind == KIND_GROUND {
                // What `local` adds on the ground: the open sky's irradiance.
                first_light = surf.albedo * open_sky_on_ground();
            }
            // Next: reflect or transmit, picked in proportion to how much
            // each carries; or, at a gather's far end, the rest of the
            // light from the lattice.
            let pr = mean3(reflect_c);
            let pt = mean3(transmit_c);
            if gathering() && depth >= frame.gather_bounces {
                light += beta * gather_far_end(surf, n);
                alive = false;
            } else if pr + pt <= 0.0 {
                alive = false;
            } else if rand() * (pr + pt) < pr {
                beta *= reflect_c * ((pr + pt) / pr);
                ray = make_ray(surf.p + n * frame.epsilon, cosine_direction(n));
            } else {
                beta *= transmit_c * ((pr + pt) / pt);
                ray = make_ray(surf.p - n * frame.epsilon, cosine_direction(-n));
            }
        }
        if any(sun_light > vec3<f32>(0.0)) {
            let sun = sun_light * sun_visibility(sun_from);
            light += sun;
            // At the camera's own surface (not a cloud), the direct pass.
            if depth == 0u && !(HAS_CLOUDS && hit.x >= 0.0) {
                first_split = vec4<f32>(sun, 0.0);
            }
        }
        if depth == 0u {
            first_light += light;
        }
        // Russian roulette after three bounces keeps the estimate unbiased.
        if alive && depth >= 3u {
            let q = min(max(beta.x, max(beta.y, beta.z)), 0.95);
            if rand() >= q {
                alive = false;
            } else {
                beta /= q;
            }
        }
        depth += 1u;
    }
    // The indirect light of a sample whose first event is a surface: what
    // the gathers' filter averages as that surface's irradiance. A sample
    // that scattered in a cloud first lit no surface; its part of
    // `light − first_light` is the cloud's, and spread as leaf irradiance
    // (divided by the few leaf samples' albedo) it whitened the crowns
    // in front of a cloud.
    let surface_indirect = select(vec3<f32>(0.0), light - first_light, first_surface_hit > 0.0);
    return array<vec4<f32>, 7>(vec4<f32>(light, coverage), vec4<f32>(first_light, first_depth), vec4<f32>(first_albedo, first_surface_hit), vec4<f32>(surface_indirect, 0.0), first_split, first_normal, first_ids);
}
