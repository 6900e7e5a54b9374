// Geometry views (src/gpu/geometry.rs, GeometryView): how a kernel reads triangles out of a caller's buffers. A
// kernel that reads geometry declares these six members first in its push-constant block, in this order:
//   uint64_t positions;     Address of the position (f32 xyz) of vertex 0 of the view.
//   uint64_t indices;       Address of the first index (unused for a non-indexed list).
//   uint64_t vertex_count;  Vertices addressable from `positions`.
//   uint vertex_stride;     Bytes from one vertex's position to the next (a multiple of 4, at least 12).
//   uint index_type;        GEOMETRY_INDEX_NONE, GEOMETRY_INDEX_U16 or GEOMETRY_INDEX_U32.
//   uint base_vertex;       Added to every index before the vertex is read.
//   uint geometry_pad;      Padding.
// and includes this file after the block (the functions read `pc`). Triangle t of a non-indexed list is vertices
// 3t, 3t + 1, 3t + 2; of an indexed one the three indices at t. A vertex number at or past `vertex_count` reads the
// last vertex instead: a bad index in an engine's buffer gives a wrong triangle, never a read outside the view.
// 16-bit indices are read through the aligned 32-bit word that holds them (the view keeps that word readable).
#ifndef MESHCHAR_GEOMETRY_GLSL
#define MESHCHAR_GEOMETRY_GLSL

#define GEOMETRY_INDEX_NONE 0u  // Geometry view: a non-indexed triangle list.
#define GEOMETRY_INDEX_U16 1u   // Geometry view: 16-bit indices.
#define GEOMETRY_INDEX_U32 2u   // Geometry view: 32-bit indices.

uint geometry_u16(uint64_t at) {
    uint w = U32Ref(at & ~3ul).v;
    return (at & 2ul) != 0ul ? (w >> 16) : (w & 0xffffu);
}

// The vertex numbers of triangle t (base vertex not yet added).
u64vec3 geometry_triangle(uint64_t t) {
    if (pc.index_type == GEOMETRY_INDEX_U32) {
        return u64vec3(ld_uvec3(pc.indices, t));
    }
    if (pc.index_type == GEOMETRY_INDEX_U16) {
        uint64_t at = pc.indices + 6ul * t;
        return u64vec3(geometry_u16(at), geometry_u16(at + 2ul), geometry_u16(at + 4ul));
    }
    return u64vec3(3ul * t, 3ul * t + 1ul, 3ul * t + 2ul);
}

// The position of vertex number v of an index (the base vertex is added here).
vec3 geometry_vertex(uint64_t v) {
    uint64_t i = min(v + uint64_t(pc.base_vertex), pc.vertex_count - 1ul);
    Vec3Ref r = Vec3Ref(pc.positions + i * uint64_t(pc.vertex_stride));
    return vec3(r.x, r.y, r.z);
}

#endif
