// The field grid (passes/field_grid.py): the frame's particle centres (view space) counting-
// sorted into a hashed uniform grid of cell side grid_cell_side() = h / FIELD_CELLS_PER_SUPPORT
// (h = u_support, the SPH support), so a point's neighbours within h lie in the (2 m + 1)^3
// cells around its own (m = FIELD_CELLS_PER_SUPPORT). Built by field/field_grid.comp.glsl, read
// by field/field_normals.glsl.
//   bucket(cell) = (x + y FIELD_HASH_Y + z FIELD_HASH_Z) & u_bucket_mask over a power-of-two
//   table of at least FIELD_MIN_BUCKETS: linear in x, so a row of cells along x is a run of
//   consecutive buckets (wrapping at the table's end) and its centres one contiguous range of
//   the sorted array; starts[b] .. starts[b + 1]: the sorted centres of the cells that hash to
//   bucket b (cells far apart may share one; a reader's distance test drops those).
//   No two rows of one reader's window share a bucket: for |dy|, |dz| <= 2 m, not both 0,
//   dy FIELD_HASH_Y + dz FIELD_HASH_Z lies more than 4 m from every multiple of
//   FIELD_MIN_BUCKETS (which divides every table size); two runs of at most 2 m + 1 buckets
//   whose first cells are at most 2 m apart overlap only within 4 m (tests/test_field_normals.py
//   checks the constants). So a reader visits every centre at most once, with no per-cell tag.
// Cells come from floor(p / grid_cell_side()) clamped to +-2^30, so huge or tiny coordinates
// give finite, consistent cells (a clamped cell only merges far-away particles into one
// bucket, whose distance test still rejects them).

#define FIELD_CELLS_PER_SUPPORT 2
#define FIELD_MIN_BUCKETS 1024u
#define FIELD_HASH_Y 19349663u
#define FIELD_HASH_Z 83492791u
// A bucket holds at most FIELD_SLOTS sorted entries (field/field_grid.comp.glsl's phase 8 merges
// a crowded one into weighted slots, one per sub-cell of FIELD_SLOT_SIDE^3 per cell).
#define FIELD_SLOTS 64u
#define FIELD_SLOT_SIDE 4u

uniform float u_support;     // h, view-space units
uniform uint u_bucket_mask;  // table size - 1 (a power of two, >= FIELD_MIN_BUCKETS - 1)

// The same expression in the build and in every reader, so all agree on a centre's cell.
float grid_cell_side() {
    return u_support / float(FIELD_CELLS_PER_SUPPORT);
}

ivec3 grid_cell(vec3 p) {
    return ivec3(floor(clamp(p / grid_cell_side(), vec3(-1073741824.0), vec3(1073741824.0))));
}

// The unmasked hash: bucket = grid_hash(cell) & u_bucket_mask; x + 1 is the next bucket.
uint grid_hash(ivec3 c) {
    return uint(c.x) + uint(c.y) * FIELD_HASH_Y + uint(c.z) * FIELD_HASH_Z;
}

uint grid_bucket(ivec3 c) {
    return grid_hash(c) & u_bucket_mask;
}
