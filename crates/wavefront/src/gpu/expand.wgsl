// HistoPyramid traversal (see histopyramid.wgsl): one thread per output
// slot k walks from the top level down, stepping into the child whose
// running sum covers k and subtracting the sums it skipped. At the base,
// `node` is the source patch and what is left of k says which of its
// slots (which quarter, for a tessellated patch) the slot takes:
// compaction and expansion in one pass.

@group(0) @binding(0) var<storage, read> levels: array<u32>;
@group(0) @binding(1) var<storage, read> info: array<u32>;
@group(0) @binding(2) var<storage, read_write> source: array<u32>;
@group(0) @binding(3) var<storage, read_write> part: array<u32>;

@compute @workgroup_size(64)
fn expand(@builtin(global_invocation_id) id: vec3<u32>,
          @builtin(num_workgroups) groups: vec3<u32>) {
    let k = id.x + id.y * groups.x * 64u;
    let depth = info[0];
    let total = levels[info[depth]];
    if (k >= total) {
        return;
    }
    var rest = k;
    var node = 0u;
    var l = depth - 1u;
    loop {
        if (l == 0u) {
            break;
        }
        l -= 1u;
        let offset = info[1u + l];
        let len = info[1u + depth + l];
        let first = 4u * node;
        var child = first;
        // At most three skips: the choice among four children.
        let last = min(first + 3u, len - 1u);
        for (var c = first; c < last; c++) {
            let v = levels[offset + c];
            if (rest < v) {
                break;
            }
            rest -= v;
            child += 1u;
        }
        node = child;
    }
    source[k] = node;
    part[k] = rest;
}
