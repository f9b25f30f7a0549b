// The field grid (passes/field_grid.py): the frame's particle centres (view space) counting-
// sorted into a hashed uniform grid of cell side u_support (the SPH support h), so a point's
// neighbours within h lie in the 27 cells around its own. Built by field/field_grid.comp.glsl,
// read by field/field_normals.frag.glsl.
//   bucket(cell) = Teschner et al. (2003) hash & u_bucket_mask over a power-of-two table;
//   starts[b] .. starts[b + 1]: the sorted centres of the cells that hash to bucket b; a bucket
//   may hold several cells, so each centre carries a second, independent hash of its cell
//   (grid_tag, in w as bits) and readers take only the centres whose tag is their cell's.
// Cells come from floor(p / h) clamped to +-2^30, so huge or tiny coordinates give finite,
// consistent cells (a clamped cell only merges far-away particles into one bucket, whose
// distance test still rejects them).

uniform float u_support;     // h, view-space units
uniform uint u_bucket_mask;  // table size - 1 (a power of two)

ivec3 grid_cell(vec3 p) {
    return ivec3(floor(clamp(p / u_support, vec3(-1073741824.0), vec3(1073741824.0))));
}

uint grid_bucket(ivec3 c) {
    return ((uint(c.x) * 73856093u) ^ (uint(c.y) * 19349663u) ^ (uint(c.z) * 83492791u))
        & u_bucket_mask;
}

// A cell's tag: a 32-bit mix of its coordinates independent of the bucket (two cells of one
// bucket share a tag with probability ~2^-32), never 0.
uint grid_tag(ivec3 c) {
    uint h = uint(c.x) * 0x9E3779B1u;
    h = (h ^ (h >> 15)) + uint(c.y) * 0x85EBCA77u;
    h = (h ^ (h >> 13)) + uint(c.z) * 0xC2B2AE3Du;
    h ^= h >> 16;
    return h | 1u;
}
