// HistoPyramid stream compaction and expansion (`histopyramid.rs`; Ziegler
// et al. 2006, as extended in [Ihrke07 sec 5.2.3]). A pyramid over n
// entries lies in `pyramid` from `base` on: level 0 the n entries, level
// l + 1 the sums of groups of four of level l, back to back. Building it
// is one dispatch per level (`hp_reduce`, one thread per entry of the
// level); then each output slot finds its source entry by one walk from
// the top (`hp_locate`).
//
// Hook: `var<storage, read_write> pyramid: array<u32>`, holding the
// kernel's pyramids.

// Levels of a pyramid over n entries (at least one).
fn hp_depth(n: u32) -> u32 {
    var d = 1u;
    var len = max(n, 1u);
    while len > 1u {
        len = (len + 3u) / 4u;
        d += 1u;
    }
    return d;
}

// Entries of level l.
fn hp_len(l: u32, n: u32) -> u32 {
    var len = max(n, 1u);
    for (var m = 0u; m < l; m++) {
        len = (len + 3u) / 4u;
    }
    return len;
}

// Where level l starts, relative to the pyramid's base.
fn hp_offset(l: u32, n: u32) -> u32 {
    var off = 0u;
    var len = max(n, 1u);
    for (var m = 0u; m < l; m++) {
        off += len;
        len = (len + 3u) / 4u;
    }
    return off;
}

// Entry j of level l >= 1: the sum of its (up to) four children.
fn hp_reduce(base: u32, n: u32, l: u32, j: u32) {
    if j >= hp_len(l, n) {
        return;
    }
    let src = base + hp_offset(l - 1u, n);
    let src_len = hp_len(l - 1u, n);
    var sum = 0u;
    for (var c = 0u; c < 4u; c++) {
        if 4u * j + c < src_len {
            sum += pyramid[src + 4u * j + c];
        }
    }
    pyramid[src + src_len + j] = sum;
}

// The sum of all entries: the top.
fn hp_total(base: u32, n: u32) -> u32 {
    return pyramid[base + hp_offset(hp_depth(n) - 1u, n)];
}

// `HistoPyramid::locate`: output slot k's source entry and which of its
// slots k is (x, y). At each level the walk steps into the child whose
// running sum covers k, subtracting the sums it skips (at most three).
fn hp_locate(base: u32, n: u32, k: u32) -> vec2<u32> {
    var rest = k;
    var node = 0u;
    var l = hp_depth(n) - 1u;
    loop {
        if l == 0u {
            break;
        }
        l -= 1u;
        let offset = base + hp_offset(l, n);
        let first = 4u * node;
        var child = first;
        let last = min(first + 3u, hp_len(l, n) - 1u);
        for (var c = first; c < last; c++) {
            let v = pyramid[offset + c];
            if rest < v {
                break;
            }
            rest -= v;
            child += 1u;
        }
        node = child;
    }
    return vec2<u32>(node, rest);
}

// The sum of the entries before entry i: its left siblings' sums on the
// way up.
fn hp_rank(base: u32, n: u32, i: u32) -> u32 {
    var rank = 0u;
    var node = i;
    var off = base;
    var len = max(n, 1u);
    let depth = hp_depth(n);
    for (var l = 0u; l + 1u < depth; l++) {
        for (var c = node & ~3u; c < node; c++) {
            rank += pyramid[off + c];
        }
        off += len;
        len = (len + 3u) / 4u;
        node = node >> 2u;
    }
    return rank;
}
