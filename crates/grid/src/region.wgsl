// Sharp interfaces (`region.rs`): the scene's regions, each object's
// interior after priorities and the ambient medium, each with its own index
// profile, separated by the objects' exact surfaces (the `surface` module).
//
// The table of regions is `RegionGpu` (generated), the objects in
// precedence order (highest priority first), then the ambient medium at
// index `region_count()`. A kernel provides the hooks
// `region_count() -> u32` and `region_object(i: u32) -> RegionGpu`, and the
// `surface` module's `surface_data(i: u32) -> vec4<u32>` (the data buffer
// of `GpuRegions::data`: profiles, mesh triangles and BVH nodes).
//
// Needs: `RegionGpu`, `SHAPE_*`, `PROFILE_*`, `FLAG_*` (generated), the
// `vector`, `surface` and `fresnel` modules.

fn region_rot(r: RegionGpu) -> mat3x3<f32> {
    return mat3x3<f32>(r.axis_x, r.axis_y, r.axis_z);
}

// Whether the kernel holds the code of shape `kind` (`REGION_KINDS`, a bit
// per kind: every kind unless `region::only_kinds` narrowed it). Drivers
// inline every call, so a kernel that compiled every shape's code at each
// call site grew too large to compile in time on lavapipe; a constant
// false branch is dropped before that.
fn region_has(kind: u32) -> bool {
    return (REGION_KINDS & (1u << kind)) != 0u;
}

// Region r's mesh in the data buffer.
fn region_mesh(r: RegionGpu) -> SurfaceMesh {
    return SurfaceMesh(r.data, r.nodes, r.node_count, (r.flags & FLAG_SMOOTH) != 0u);
}

// `Shape::first_crossing` of region r's shape (d unit) on lo < t <= hi.
fn region_shape_crossing(r: RegionGpu, o: vec3<f32>, d: vec3<f32>, lo: f32, hi: f32) -> SurfaceHit {
    switch r.kind {
        case SHAPE_SPHERE: {
            return surface_sphere(o, d, r.center, r.radius, lo, hi);
        }
        case SHAPE_BOX: {
            return surface_box(o, d, r.center, region_rot(r), r.half, lo, hi);
        }
        case SHAPE_CYLINDER: {
            return surface_cylinder(o, d, r.center, region_rot(r), r.radius, r.half.y, lo, hi);
        }
        case SHAPE_HALF_SPACE: {
            return surface_half_space(o, d, r.center, r.half, lo, hi);
        }
        case SHAPE_ROUNDED_BOX: {
            if region_has(SHAPE_ROUNDED_BOX) {
                return surface_rounded_box(o, d, r.center, region_rot(r), r.half, r.radius, lo, hi);
            }
        }
        case SHAPE_REVOLUTION: {
            if region_has(SHAPE_REVOLUTION) {
                return surface_revolution(o, d, r.center, region_rot(r), r.data, r.data_len, lo, hi);
            }
        }
        case SHAPE_TORUS: {
            if region_has(SHAPE_TORUS) {
                return surface_torus(o, d, r.center, region_rot(r), r.radius, r.shape_a, r.size, lo, hi);
            }
        }
        case SHAPE_SUPERQUADRIC: {
            if region_has(SHAPE_SUPERQUADRIC) {
                return surface_superquadric(o, d, r.center, region_rot(r), r.half, r.shape_a, r.shape_b, r.size, lo, hi);
            }
        }
        case SHAPE_MESH: {
            if region_has(SHAPE_MESH) {
                return surface_mesh(region_mesh(r), o, d, lo, hi);
            }
        }
        case SHAPE_VDB: {
            if region_has(SHAPE_VDB) {
                return surface_vdb(r.data, r.radius, o, d, lo, hi);
            }
        }
        default: {
            return surface_miss();
        }
    }
    return surface_miss();
}

// `Shape::distance` of region r's shape (negative inside).
fn region_shape_distance(r: RegionGpu, p: vec3<f32>) -> f32 {
    if r.kind == SHAPE_MESH && region_has(SHAPE_MESH) {
        return surface_mesh_distance(region_mesh(r), p);
    }
    return region_solid_distance(r, p);
}

// `Shape::distance` of every shape but the mesh (whose nearest-triangle
// search `region_shape_contains` does without: drivers inline each call,
// so code that cannot run there is left out). For a VDB grid only its
// sign: the threshold less the grid's value (negative inside, as
// `VdbSolid::contains`); the kernels read no more of it.
fn region_solid_distance(r: RegionGpu, p: vec3<f32>) -> f32 {
    switch r.kind {
        case SHAPE_SPHERE: {
            return length(p - r.center) - r.radius;
        }
        case SHAPE_BOX: {
            return surface_box_distance(p, r.center, region_rot(r), r.half);
        }
        case SHAPE_CYLINDER: {
            return surface_cylinder_distance(p, r.center, region_rot(r), r.radius, r.half.y);
        }
        case SHAPE_HALF_SPACE: {
            return dot(p - r.center, r.half);
        }
        case SHAPE_ROUNDED_BOX: {
            if region_has(SHAPE_ROUNDED_BOX) {
                return surface_rounded_box_distance(p, r.center, region_rot(r), r.half, r.radius);
            }
        }
        case SHAPE_REVOLUTION: {
            if region_has(SHAPE_REVOLUTION) {
                return surface_revolution_distance(p, r.center, region_rot(r), r.data, r.data_len);
            }
        }
        case SHAPE_TORUS: {
            if region_has(SHAPE_TORUS) {
                return surface_torus_distance((p - r.center) * region_rot(r), r.radius, r.shape_a);
            }
        }
        case SHAPE_SUPERQUADRIC: {
            if region_has(SHAPE_SUPERQUADRIC) {
                return surface_superquadric_distance((p - r.center) * region_rot(r), r.half, r.shape_a, r.shape_b);
            }
        }
        case SHAPE_VDB: {
            if region_has(SHAPE_VDB) {
                return r.radius - surface_vdb_sample(r.data, p);
            }
        }
        default: {
            return SURFACE_FAR;
        }
    }
    return SURFACE_FAR;
}

// `Shape::normal` of region r's shape at (or nearest to) p.
fn region_shape_normal(r: RegionGpu, p: vec3<f32>) -> vec3<f32> {
    switch r.kind {
        case SHAPE_SPHERE: {
            return surface_unit_or(p - r.center, vec3<f32>(0.0, 1.0, 0.0));
        }
        case SHAPE_BOX: {
            return surface_box_normal(p, r.center, region_rot(r), r.half);
        }
        case SHAPE_CYLINDER: {
            return surface_cylinder_normal(p, r.center, region_rot(r), r.radius, r.half.y);
        }
        case SHAPE_ROUNDED_BOX: {
            if region_has(SHAPE_ROUNDED_BOX) {
                return surface_rounded_box_normal(p, r.center, region_rot(r), r.half, r.radius);
            }
        }
        case SHAPE_REVOLUTION: {
            if region_has(SHAPE_REVOLUTION) {
                return surface_revolution_normal(p, r.center, region_rot(r), r.data, r.data_len);
            }
        }
        case SHAPE_TORUS: {
            if region_has(SHAPE_TORUS) {
                return region_rot(r) * surface_torus_normal((p - r.center) * region_rot(r), r.radius);
            }
        }
        case SHAPE_SUPERQUADRIC: {
            if region_has(SHAPE_SUPERQUADRIC) {
                return region_rot(r) * surface_superquadric_normal((p - r.center) * region_rot(r), r.half, r.shape_a, r.shape_b, r.size);
            }
        }
        case SHAPE_MESH: {
            if region_has(SHAPE_MESH) {
                return surface_mesh_normal(region_mesh(r), p);
            }
        }
        case SHAPE_VDB: {
            if region_has(SHAPE_VDB) {
                return surface_vdb_normal(r.data, p);
            }
        }
        default: {
            return r.half;
        }
    }
    return r.half;
}

// `Shape::contains` of region r's shape: the sign of its distance, for a
// mesh the parity alone (its distance needs a nearest-triangle search).
fn region_shape_contains(r: RegionGpu, p: vec3<f32>) -> bool {
    if r.kind == SHAPE_MESH && region_has(SHAPE_MESH) {
        return surface_mesh_inside(region_mesh(r), p);
    }
    return region_solid_distance(r, p) < 0.0;
}

// `Scene::owner`: the region that owns p, the first object in precedence
// order that contains it, else the ambient medium.
fn region_owner(p: vec3<f32>) -> u32 {
    let count = region_count();
    for (var i = 0u; i < count; i++) {
        if region_shape_contains(region_object(i), p) {
            return i;
        }
    }
    return count;
}

// `Regions::index` (`IndexProfile::sample`): region r's index at p for
// channel ch and its gradient, (n, grad n).
fn region_index(ri: u32, p: vec3<f32>, ch: u32) -> vec4<f32> {
    let r = region_object(ri);
    switch r.profile {
        case PROFILE_LUNEBURG: {
            let d = p - r.index;
            let rr = r.index_a * r.index_a;
            let s = max(2.0 - dot(d, d) / rr, 1.0);
            let outer = r.index_b;
            let n = outer * sqrt(s);
            return vec4<f32>(n, -d * (outer * outer) / (rr * n));
        }
        case PROFILE_LINEAR: {
            return vec4<f32>(r.index_a + dot(r.index, p - r.index_origin), r.index);
        }
        case PROFILE_VDB: {
            if !region_has(KIND_GRID_INDEX) {
                return vec4<f32>(1.0, vec3<f32>(0.0));
            }
            // The grid's value (scaled), its gradient by central
            // differences half a grid voxel either way.
            let v = r.index_volume;
            let h = 0.5 * abs(surface_data_f(v).x);
            let n = r.index_b + r.index_a * surface_vdb_sample(v, p);
            // Written out: a loop here would count towards lavapipe's
            // budget of loop iterations at every sample (see `surface`).
            let ex = vec3<f32>(h, 0.0, 0.0);
            let ey = vec3<f32>(0.0, h, 0.0);
            let ez = vec3<f32>(0.0, 0.0, h);
            let g = vec3<f32>(
                surface_vdb_sample(v, p + ex) - surface_vdb_sample(v, p - ex),
                surface_vdb_sample(v, p + ey) - surface_vdb_sample(v, p - ey),
                surface_vdb_sample(v, p + ez) - surface_vdb_sample(v, p - ez),
            ) * (r.index_a / (2.0 * h));
            return vec4<f32>(n, g);
        }
        default: {
            return vec4<f32>(r.index[min(ch, 2u)], vec3<f32>(0.0));
        }
    }
}

// `Material::extinction_at`: region r's RGB extinction at p (from its
// extinction grid where it has one).
fn region_extinction(ri: u32, p: vec3<f32>) -> vec3<f32> {
    let r = region_object(ri);
    if r.ext_volume == NO_VOLUME || !region_has(KIND_GRID_EXTINCTION) {
        return r.extinction;
    }
    return r.extinction * surface_vdb_sample(r.ext_volume, p);
}

// `Regions::uniform`: region r's index is one constant.
fn region_uniform(ri: u32) -> bool {
    return region_object(ri).profile == PROFILE_CONSTANT;
}

struct RegionHit {
    ok: bool,
    // The surface's region (object in precedence order).
    obj: u32,
    t: f32,
    normal: vec3<f32>,
}

// `Regions::next_surface`: the first surface the segment o + d t,
// eps < t <= t_max, crosses (d unit).
fn region_next_surface(o: vec3<f32>, d: vec3<f32>, eps: f32, t_max: f32) -> RegionHit {
    var best = RegionHit(false, 0u, t_max, vec3<f32>(0.0));
    let count = region_count();
    for (var i = 0u; i < count; i++) {
        let c = region_shape_crossing(region_object(i), o, d, eps, best.t);
        if c.ok && (!best.ok || c.t < best.t) {
            best = RegionHit(true, i, c.t, c.normal);
        }
    }
    return best;
}

// `region::refract`: Snell's law for the eikonal gradient v crossing the
// unit normal (along the travel) into index n2: the tangential part kept,
// the normal part of the length that makes |v| = n2; w = 0 under total
// internal reflection, else 1.
fn region_refract(v: vec3<f32>, normal: vec3<f32>, n2: f32) -> vec4<f32> {
    let vn = dot(v, normal);
    let vt = v - normal * vn;
    let rest = n2 * n2 - dot(vt, vt);
    if rest >= 0.0 {
        return vec4<f32>(vt + normal * sqrt(rest), 1.0);
    }
    return vec4<f32>(v, 0.0);
}

// What `Regions::cross` found at a surface.
struct RegionCross {
    // A true crossing (the owner changes); false: nothing happened.
    event: bool,
    // The surface reflected the ray totally (it stays in its region).
    total: bool,
    // The region the ray is in afterwards.
    region: u32,
    // Its eikonal gradient afterwards.
    v: vec3<f32>,
    // The unit normal along the travel, the incident unit direction.
    normal: vec3<f32>,
    incident: vec3<f32>,
    // Fresnel reflectance (1 under total internal reflection).
    reflectance: f32,
}

// `Regions::cross`: a ray in region `here` with eikonal gradient v is at
// `point` on a surface of unit outward `normal`: the region beyond (probed
// eps along the normal), and the ray refracted or reflected there. No
// event when the owner does not change (a false crossing).
fn region_cross(here: u32, v: vec3<f32>, point: vec3<f32>, normal: vec3<f32>, eps: f32, ch: u32) -> RegionCross {
    let d = normalize_or_zero(v);
    let along = select(-normal, normal, dot(d, normal) >= 0.0);
    let to = region_owner(point + along * eps);
    var out = RegionCross(false, false, here, v, along, d, 0.0);
    if to == here {
        return out;
    }
    let n1 = region_index(here, point, ch).x;
    let n2 = region_index(to, point, ch).x;
    let vi = d * n1;
    let cos_i = dot(d, along);
    out.event = true;
    let r = region_refract(vi, along, n2);
    if r.w != 0.0 {
        out.v = r.xyz;
        out.region = to;
        out.reflectance = fresnel_reflectance(cos_i, n1, n2);
    } else {
        out.v = vi - along * (2.0 * dot(vi, along));
        out.total = true;
        out.reflectance = 1.0;
    }
    return out;
}
