// requires: common/octree.wgsl common/traverse.wgsl common/optics.wgsl
// Ray tracing kernel: one thread per pixel of a band of rows, looping over the pixel's samples.
// Twin of crates/pc-raytrace/src/cpu.rs (trace_sample with Path::follow and shade_diffuse,
// direct, phong), line by line but for the branches' loop, and of the traversal in
// crates/pc-tree/src/ray.rs; shares shaders/common/octree.wgsl. Threads run in 8x8 pixel
// blocks, so neighbouring rays (coherent, §8.5.14) share a workgroup.

struct PointLight {
    position: vec3<f32>,
    _pad0: f32,
    intensity: vec3<f32>,
    _pad1: f32,
}

struct Params {
    cam_origin: vec3<f32>,
    width: u32,
    cam_forward: vec3<f32>,
    height: u32,
    cam_right: vec3<f32>,
    spp: u32,
    cam_up: vec3<f32>,
    max_bounces: u32,
    background: vec3<f32>,
    mode: u32,
    tan_half: vec2<f32>,
    self_hit: f32,
    blend_thickness: f32,
    light_samples: u32,
    light_count: u32,
    emitter_count: u32,
    seed: u32,
    row_offset: u32,
    rows: u32,
    // 1: diffuse hits show the per-splat radiance of `radiance` (pc-fmm's artifact).
    stored_radiance: u32,
    // The photon map (twin of crate::photon_grid::PhotonGrid): density-estimate radius, photons in
    // `photons` (0: no caustic term), spatial hash of cells of side grid_cell from grid_origin.
    caustic_radius: f32,
    grid_origin: vec3<f32>,
    grid_mask: u32,
    photon_count: u32,
    grid_cell: f32,
    // 1: out_pixels holds three words of four per pixel (colour and depth, normal and splat,
    // albedo: PixelOut's layout), 0: one (colour and depth), a third of the bytes to read back.
    aovs: u32,
    // 1: the second pass of refined pixels (crate::refine): only the pixels whose word's fourth
    // lane the host set to REFINE_MARK are rendered, the others left as they are.
    refine: u32,
    // Dielectric hits per sample that take both ways out (raytrace.splits, at most 3).
    splits: u32,
    // This dispatch's samples of each pixel: sample_count of them from sample_offset, added to
    // the sums the dispatch before left in out_pixels (several dispatches on a software
    // adapter, whose loops end after 65535 iterations per invocation group; crate::gpu::render).
    sample_offset: u32,
    sample_count: u32,
    _pad0: u32,
}

// A camera sample's branch waiting to be traced (twin of an entry of cpu.rs's Branches): its
// ray, throughput and the bounce it starts at.
struct Branch {
    ro: vec3<f32>,
    rd: vec3<f32>,
    t_min: f32,
    throughput: vec3<f32>,
    bounce: u32,
}

// The branches waiting, last in first out: at most pc_config::MAX_SPLITS (3) at once, in
// named slots (no array indexed per thread).
struct Slots {
    s0: Branch,
    s1: Branch,
    s2: Branch,
    n: u32,
}

fn push_branch(slots: ptr<function, Slots>, b: Branch) {
    switch (*slots).n {
        case 0u: { (*slots).s0 = b; }
        case 1u: { (*slots).s1 = b; }
        default: { (*slots).s2 = b; }
    }
    (*slots).n = (*slots).n + 1u;
}

fn pop_branch(slots: ptr<function, Slots>) -> Branch {
    (*slots).n = (*slots).n - 1u;
    switch (*slots).n {
        case 0u: { return (*slots).s0; }
        case 1u: { return (*slots).s1; }
        default: { return (*slots).s2; }
    }
}

// Twin of pc_raytrace::refine::MARK.
const REFINE_MARK: u32 = 0xffffffffu;
// Twin of pc_tree::ray::BLEND_MIN_COS: the least cosine between a covering splat's normal and
// the hit's for the two to blend.
const BLEND_MIN_COS: f32 = 0.5;

// A stored photon (twin of pc_artifact::photons::Photon).
struct Photon {
    position: vec3<f32>,
    splat: u32,
    dir: vec3<f32>,
    bounces: u32,
    power: vec3<f32>,
    _pad: u32,
}

// A dense bucket's photons: their mean position (the moments' origin), the bounds of positions
// and directions about it, and per channel the power moments Σ Φ, Σ Φ |p − q|², Σ Φ (p − q)
// (one row per channel); the photons in `photons` (twin of crate::photon_grid::PhotonGroup).
struct PhotonGroup {
    position: vec3<f32>,
    extent: f32,
    dir: vec3<f32>,
    dir_extent: f32,
    power: vec3<f32>,
    start: u32,
    second: vec3<f32>,
    count: u32,
    first_r: vec4<f32>,
    first_g: vec4<f32>,
    first_b: vec4<f32>,
}

struct PixelOut {
    rgb: vec3<f32>,
    depth: f32,
    normal: vec3<f32>,
    splat: u32,
    albedo: vec3<f32>,
    _pad: u32,
}

@group(0) @binding(0) var<uniform> octree_frame: Frame;
@group(0) @binding(1) var<storage, read> octree_nodes: array<u32>;
@group(0) @binding(2) var<storage, read> begin_end: array<u32>;
@group(0) @binding(3) var<storage, read> splats: array<Splat>;
@group(0) @binding(4) var<storage, read> node_info: array<NodeInfo>;
@group(0) @binding(5) var<storage, read> splat_area: array<f32>;
@group(0) @binding(6) var<storage, read> splat_leaf: array<u32>;
@group(0) @binding(7) var<storage, read> materials: array<Material>;
@group(0) @binding(8) var<storage, read> lights: array<PointLight>;
// Emitter table: x = data-pool index, y = bits of the inclusive CDF.
@group(0) @binding(9) var<storage, read> emitters: array<vec2<u32>>;
@group(0) @binding(10) var<uniform> params: Params;
@group(0) @binding(11) var<storage, read_write> out_pixels: array<vec4<u32>>;
// Per splat outgoing diffuse radiance (RGB, three floats per splat, as the radiosity artifact
// holds it) when params.stored_radiance == 1.
@group(0) @binding(12) var<storage, read> radiance: array<f32>;

// The stored radiance of splat j.
fn stored_radiance(j: u32) -> vec3<f32> {
    return vec3<f32>(radiance[3u * j], radiance[3u * j + 1u], radiance[3u * j + 2u]);
}
// The sparse buckets' photons sorted by hash bucket, then the groups' photons, and each
// bucket's first photon (params.grid_mask + 2 entries) followed by each bucket's first group (as
// many).
@group(0) @binding(13) var<storage, read> photons: array<Photon>;
@group(0) @binding(14) var<storage, read> grid_offsets: array<u32>;
// Each octree leaf's roughness per node-pool slot (pc_tree::between::leaf_roughness) in direct
// mode, for the shadow rays' own zones.
@group(0) @binding(15) var<storage, read> leaf_rough: array<f32>;
// The dense buckets' groups of photons (twin of crate::photon_grid::PhotonGroup).
@group(0) @binding(16) var<storage, read> photon_groups: array<PhotonGroup>;

// A shadow ray leaving the surface of splat `own`, past that surface's own roughness (twin of
// RenderScene::occluded_leaving).
fn occluded_leaving(x: vec3<f32>, dir: vec3<f32>, t_min: f32, t_max: f32, own: u32) -> bool {
    let s = splats[own];
    let ends = leaving(s, leaf_rough[splat_leaf[own]], dir);
    return trace_between(x, dir, t_min, t_max, true, ends).found;
}

const F32_MAX: f32 = 3.40282347e38;

// ---- sample pattern (twin of sample.rs) -----------------------------------------------------

fn rand(pixel: u32, k: u32, d: u32) -> f32 {
    return rand4(params.seed, pixel, k, d);
}

fn dim(bounce: u32, i: u32) -> u32 {
    return 2u + bounce * 16u + i;
}

fn pixel_offset(pixel: u32, k: u32) -> vec2<f32> {
    let jx = rand(pixel, k, 0u);
    let jy = rand(pixel, k, 1u);
    let g = u32(sqrt(f32(params.spp)));
    if g * g == params.spp && g > 1u {
        let gf = f32(g);
        return vec2<f32>((f32(k % g) + jx) / gf, (f32(k / g) + jy) / gf);
    }
    return vec2<f32>(jx, jy);
}

// ---- shading (twins of cpu.rs) --------------------------------------------------------------

fn emitter_pick(u: f32) -> u32 {
    // First inclusive-CDF entry > u (binary search), clamped to the last.
    var lo = 0u;
    var hi = params.emitter_count;
    loop {
        if lo >= hi {
            break;
        }
        let mid = (lo + hi) / 2u;
        if bitcast<f32>(emitters[mid].y) <= u {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return min(lo, params.emitter_count - 1u);
}

fn emitter_pdf(k: u32) -> f32 {
    var prev = 0.0;
    if k > 0u {
        prev = bitcast<f32>(emitters[k - 1u].y);
    }
    return bitcast<f32>(emitters[k].y) - prev;
}

fn direct(x: vec3<f32>, n: vec3<f32>, delta: f32, own: u32, pixel: u32, k: u32, bounce: u32) -> vec3<f32> {
    var e = vec3<f32>(0.0);
    for (var li = 0u; li < params.light_count; li = li + 1u) {
        let l = lights[li];
        let to = l.position - x;
        let d2 = dot(to, to);
        let d = sqrt(d2);
        let dir = to / d;
        let c = dot(n, dir);
        if c > 0.0 && !occluded_leaving(x, dir, delta, d * (1.0 - 1e-4), own) {
            e = e + l.intensity * c / d2;
        }
    }
    if params.emitter_count > 0u {
        let inv_n = 1.0 / f32(params.light_samples);
        for (var i = 0u; i < params.light_samples; i = i + 1u) {
            let u0 = rand(pixel, k, dim(bounce, 1u + 3u * i));
            let u1 = rand(pixel, k, dim(bounce, 2u + 3u * i));
            let u2 = rand(pixel, k, dim(bounce, 3u + 3u * i));
            let ke = emitter_pick(u0);
            let j = emitters[ke].x;
            let sj = splats[j];
            let y = disk_point(sj, u1, u2);
            let to = y - x;
            let d2 = dot(to, to);
            let d = sqrt(d2);
            let dir = to / d;
            let cos_x = dot(n, dir);
            let cos_y = -dot(sj.normal, dir);
            if cos_x > 0.0 && cos_y > 0.0 && !occluded_leaving(x, dir, delta, d - params.self_hit * sj.radius, own) {
                let pdf_area = emitter_pdf(ke) / splat_area[j];
                e = e + materials[sj.material].radiance * (cos_x * cos_y / (d2 * pdf_area)) * inv_n;
            }
        }
    }
    return e;
}

// ---- caustic density estimate (twin of crate::caustic::PhotonGrid::irradiance) ---------------

fn grid_hash(c: vec3<u32>) -> u32 {
    return ((c.x * 73856093u) ^ (c.y * 19349663u) ^ (c.z * 83492791u)) & params.grid_mask;
}

// Caustic irradiance at x (unit normal n): the photons within the radius that arrived from the
// front and lie near the tangent plane, with the 2-D Epanechnikov kernel.
fn caustic(x: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    let r = params.caustic_radius;
    let r2 = r * r;
    let q = (x - params.grid_origin) / params.grid_cell;
    let c = floor(q);
    let f = q - c;
    var seen: array<u32, 8>;
    var count = 0u;
    var e = vec3<f32>(0.0);
    for (var i = 0u; i < 8u; i = i + 1u) {
        var cc = c;
        let step = select(vec3<f32>(1.0), vec3<f32>(-1.0), f < vec3<f32>(0.5));
        if (i & 1u) != 0u {
            cc.x = cc.x + step.x;
        }
        if (i & 2u) != 0u {
            cc.y = cc.y + step.y;
        }
        if (i & 4u) != 0u {
            cc.z = cc.z + step.z;
        }
        if any(cc < vec3<f32>(0.0)) {
            continue;
        }
        let h = grid_hash(vec3<u32>(cc));
        var dup = false;
        for (var j = 0u; j < count; j = j + 1u) {
            if seen[j] == h {
                dup = true;
            }
        }
        if dup {
            continue;
        }
        seen[count] = h;
        count = count + 1u;
        e = e + caustic_scan(grid_offsets[h], grid_offsets[h + 1u], x, n);
        let at = params.grid_mask + 2u + h;
        for (var k = grid_offsets[at]; k < grid_offsets[at + 1u]; k = k + 1u) {
            let g = photon_groups[k];
            let d = g.position - x;
            let d2 = dot(d, d);
            let dist = sqrt(d2);
            let facing = dot(g.dir, n);
            let off = abs(dot(d, n));
            let plane = 0.25 * r;
            // The group's bounds decide for all its photons, or leave it open (twin of
            // PhotonGroup::fate).
            if dist - g.extent > r || facing - g.dir_extent >= 0.0 || off - g.extent > plane {
                continue;
            }
            if dist + g.extent <= r && facing + g.dir_extent < 0.0 && off + g.extent <= plane {
                e = e + group_sum(g, d, r2);
            } else {
                e = e + caustic_scan(g.start, g.start + g.count, x, n);
            }
        }
    }
    return e * (2.0 / (PI * r2));
}

// Σ Φ (1 − |p − x|²/r²) over a group's photons from its moments, d = its position − x (twin of
// PhotonGroup::sum).
fn group_sum(g: PhotonGroup, d: vec3<f32>, r2: f32) -> vec3<f32> {
    let first = vec3<f32>(dot(d, g.first_r.xyz), dot(d, g.first_g.xyz), dot(d, g.first_b.xyz));
    let spread = g.second + 2.0 * first + dot(d, d) * g.power;
    return g.power - spread / r2;
}

// The kernel-weighted power of photons[lo..hi] that count at x (twin of the scan in
// PhotonGrid::irradiance).
fn caustic_scan(lo: u32, hi: u32, x: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    let r = params.caustic_radius;
    let r2 = r * r;
    var e = vec3<f32>(0.0);
    for (var k = lo; k < hi; k = k + 1u) {
        let p = photons[k];
        let d = p.position - x;
        let d2 = dot(d, d);
        if d2 <= r2 && dot(p.dir, n) < 0.0 && abs(dot(d, n)) <= 0.25 * r {
            e = e + p.power * max(1.0 - d2 / r2, 0.0);
        }
    }
    return e;
}

fn phong(x: vec3<f32>, n: vec3<f32>, wo: vec3<f32>, e: f32, delta: f32) -> vec3<f32> {
    var acc = vec3<f32>(0.0);
    for (var li = 0u; li < params.light_count; li = li + 1u) {
        let l = lights[li];
        let to = l.position - x;
        let d2 = dot(to, to);
        let d = sqrt(d2);
        let dir = to / d;
        let c = dot(n, dir);
        if c <= 0.0 {
            continue;
        }
        let spec = pow(max(dot(reflect_dir(-dir, n), wo), 0.0), e) * (e + 2.0) / (2.0 * PI);
        if spec <= 0.0 {
            continue;
        }
        if !occluded(x, dir, delta, d * (1.0 - 1e-4)) {
            acc = acc + l.intensity * spec * c / d2;
        }
    }
    return acc;
}

fn trace_sample(px: u32, py: u32, k: u32) -> PixelOut {
    var res = PixelOut(vec3<f32>(0.0), 0.0, vec3<f32>(0.0), 0xffffffffu, vec3<f32>(0.0), 0u);
    let pixel = py * params.width + px;
    let off = pixel_offset(pixel, k);
    let sx = (f32(px) + off.x) / f32(params.width);
    let sy = (f32(py) + off.y) / f32(params.height);
    let cx = (2.0 * sx - 1.0) * params.tan_half.x;
    let cy = (1.0 - 2.0 * sy) * params.tan_half.y;
    var ro = params.cam_origin;
    var rd = normalize(params.cam_forward + cx * params.cam_right + cy * params.cam_up);
    var t_min = 0.0;
    var throughput = vec3<f32>(1.0);
    var bounce = 0u;
    // The refracted branches of the path's splits at dielectrics, last split first (twin of
    // cpu.rs's Branches), and the splits made. One loop, a bounce an iteration, that takes the
    // next branch where one ends (the CPU follows each branch in a call of its own).
    var slots = Slots(Branch(), Branch(), Branch(), 0u);
    var splits = 0u;
    loop {
        var ended = true;
        if bounce <= params.max_bounces {
            let hit = trace(ro, rd, t_min, F32_MAX, false);
            if !hit.found {
                res.rgb = res.rgb + throughput * params.background;
            } else {
                let s = splats[hit.splat];
                let m = materials[s.material];
                let x = ro + rd * hit.t;
                let delta = params.self_hit * s.radius;
                let ns = s.normal;
                if m.class_id == CLASS_MIRROR || m.class_id == CLASS_DIELECTRIC {
                    let n = shading_normal(hit.splat, x);
                    let color = m.color * s.albedo;
                    if bounce == 0u {
                        res.depth = hit.t;
                        res.normal = n;
                        res.albedo = color;
                        res.splat = s.source;
                    }
                    var nf = n;
                    if dot(rd, n) >= 0.0 {
                        nf = -n;
                    }
                    if m.phong > 0.0 {
                        res.rgb = res.rgb + throughput * color * phong(x, nf, -rd, m.phong, delta);
                    }
                    var b: Bounce;
                    var halves = Split(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0), false);
                    if m.class_id == CLASS_DIELECTRIC && splits < params.splits {
                        halves = dielectric_split(m, color, ns, n, rd);
                    }
                    if halves.transmits {
                        splits = splits + 1u;
                        push_branch(&slots, Branch(x, halves.refracted, delta, throughput * halves.t_tint, bounce + 1u));
                        b = Bounce(halves.reflected, halves.r_tint);
                    } else {
                        var u = 0.0;
                        if m.class_id != CLASS_MIRROR {
                            u = rand(pixel, k, dim(bounce, 0u));
                        }
                        b = specular_bounce(m, color, ns, n, rd, u);
                    }
                    throughput = throughput * b.tint;
                    ro = x;
                    rd = b.dir;
                    t_min = delta;
                    ended = false;
                } else if dot(rd, ns) >= 0.0 {
                    // Diffuse or emitting splats are one-sided: black from behind.
                    if bounce == 0u {
                        res.depth = hit.t;
                        res.normal = ns;
                        res.splat = s.source;
                    }
                } else {
                    shade_diffuse(&res, hit, x, throughput, pixel, k, bounce);
                }
            }
        }
        if !ended {
            bounce = bounce + 1u;
        } else if slots.n > 0u {
            let next = pop_branch(&slots);
            ro = next.ro;
            rd = next.rd;
            t_min = next.t_min;
            throughput = next.throughput;
            bounce = next.bounce;
        } else {
            break;
        }
    }
    return res;
}

// A diffuse or emitting hit seen from the front ends its branch: the blend of the splats of its
// surface covering x (twin of OctreeView::covering), their stored radiance or emission, the
// caustic estimate and in direct mode the direct light, times `throughput`, added to `res`.
fn shade_diffuse(res: ptr<function, PixelOut>, hit: Hit, x: vec3<f32>, throughput: vec3<f32>, pixel: u32, k: u32, bounce: u32) {
    let s = splats[hit.splat];
    let m = materials[s.material];
    let delta = params.self_hit * s.radius;
    let ns = s.normal;
    // Blend the splats of this surface covering x (twin of OctreeView::covering).
    var wsum = 0.0;
    var albedo = vec3<f32>(0.0);
    var emit = vec3<f32>(0.0);
    var nsum = vec3<f32>(0.0);
    let off = hit.leaf & NODE_PTR;
    let begin = begin_end[off];
    let extra = begin_end[off + 1u];
    let end = begin_end[off + 2u + extra];
    let count = (end - begin) + extra;
    for (var kk = 0u; kk < count; kk = kk + 1u) {
        var j = begin + kk;
        if kk >= end - begin {
            j = begin_end[off + 2u + (kk - (end - begin))];
        }
        let sj = splats[j];
        if dot(sj.normal, ns) <= BLEND_MIN_COS {
            continue;
        }
        let dd = x - sj.position;
        let h = dot(dd, sj.normal);
        let rho2 = dot(dd, dd) - h * h;
        let r2 = sj.radius * sj.radius;
        if abs(h) <= params.blend_thickness * sj.radius && rho2 < r2 && within_clip(sj, x - sj.normal * h) {
            let uu = 1.0 - rho2 / r2;
            let wgt = uu * uu;
            let mj = materials[sj.material];
            wsum = wsum + wgt;
            albedo = albedo + wgt * mj.color * sj.albedo;
            if params.stored_radiance == 1u {
                emit = emit + wgt * stored_radiance(j);
            } else if mj.class_id == CLASS_EMITTER {
                emit = emit + wgt * mj.radiance;
            }
            nsum = nsum + wgt * sj.normal;
        }
    }
    if wsum <= 0.0 {
        wsum = 1.0;
        albedo = m.color * s.albedo;
        emit = vec3<f32>(0.0);
        if params.stored_radiance == 1u {
            emit = stored_radiance(hit.splat);
        } else if m.class_id == CLASS_EMITTER {
            emit = m.radiance;
        }
        nsum = ns;
    }
    albedo = albedo / wsum;
    emit = emit / wsum;
    var n = ns;
    if length(nsum) > 0.0 {
        n = normalize(nsum);
    }
    if bounce == 0u {
        (*res).depth = hit.t;
        (*res).normal = n;
        (*res).albedo = albedo;
        (*res).splat = s.source;
    }
    (*res).rgb = (*res).rgb + throughput * emit;
    if params.photon_count > 0u {
        (*res).rgb = (*res).rgb + throughput * albedo / PI * caustic(x, n);
    }
    if params.mode == 1u {
        (*res).rgb = (*res).rgb + throughput * albedo / PI * direct(x, n, delta, hit.splat, pixel, k, bounce);
    }
}

@compute @workgroup_size(8, 8)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let px = gid.x;
    let row = gid.y;
    if px >= params.width || row >= params.rows {
        return;
    }
    let py = params.row_offset + row;
    if params.refine == 1u && out_pixels[row * params.width + px].w != REFINE_MARK {
        return;
    }
    // The colour word: its sum so far (a dispatch before this one's samples) and the depth
    // lane, which holds the first sample's depth or, in the second pass, the host's mark.
    var w = 1u;
    if params.aovs == 1u {
        w = 3u;
    }
    let j = row * params.width + px;
    let last = params.sample_offset + params.sample_count;
    var acc = vec3<f32>(0.0);
    var lane = out_pixels[w * j].w;
    if params.sample_offset > 0u {
        acc = bitcast<vec3<f32>>(out_pixels[w * j].xyz);
    }
    for (var k = params.sample_offset; k < last; k = k + 1u) {
        let r = trace_sample(px, py, k);
        acc = acc + r.rgb;
        if k == 0u {
            if params.refine == 0u {
                lane = bitcast<u32>(r.depth);
            }
            if params.aovs == 1u {
                out_pixels[3u * j + 1u] = vec4<u32>(bitcast<vec3<u32>>(r.normal), r.splat);
                out_pixels[3u * j + 2u] = vec4<u32>(bitcast<vec3<u32>>(r.albedo), 0u);
            }
        }
    }
    if last == params.spp {
        acc = acc / f32(params.spp);
    }
    out_pixels[w * j] = vec4<u32>(bitcast<vec3<u32>>(acc), lane);
}
