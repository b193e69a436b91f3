// HistoPyramid on the GPU (Ziegler et al. 2006, as extended in Ihrke et al.
// 2007, 5.2.3): the same two steps as the CPU `histopyramid` module.
// `levels` holds every level back to back: level 0 the per-patch counts
// (0, 1 or 4), level l + 1 the sums of groups of four of level l.
// `info` = [depth, offset_0 .. offset_{depth-1}, len_0 .. len_{depth-1}].

struct Level {
    src_offset: u32,
    src_len: u32,
    dst_offset: u32,
    dst_len: u32,
}

@group(0) @binding(0) var<storage, read_write> levels: array<u32>;
@group(0) @binding(1) var<uniform> level: Level;

fn item(id: vec3<u32>, groups: vec3<u32>) -> u32 {
    return id.x + id.y * groups.x * 64u;
}

// One level of the reduction: each thread sums four entries below.
@compute @workgroup_size(64)
fn reduce(@builtin(global_invocation_id) id: vec3<u32>,
          @builtin(num_workgroups) groups: vec3<u32>) {
    let j = item(id, groups);
    if (j >= level.dst_len) {
        return;
    }
    var sum = 0u;
    for (var c = 0u; c < 4u; c++) {
        let i = 4u * j + c;
        if (i < level.src_len) {
            sum += levels[level.src_offset + i];
        }
    }
    levels[level.dst_offset + j] = sum;
}
