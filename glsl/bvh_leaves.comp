#version 460
// Leaf boxes of any BVH in the crate's layout: every leaf node gets the box of its triangles' vertices (records
// first .. first + count, triangle ids[r]); internal nodes are left alone. Used by the builds and by refit.
#include "common.glsl"
#include "bvh.glsl"

layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint ITEMS = 8;

layout(push_constant) uniform Push {
    uint64_t positions;    // Address of the position of vertex 0 (include/geometry.glsl).
    uint64_t indices;      // Address of the first index (include/geometry.glsl).
    uint64_t vertex_count; // Vertices of the view (include/geometry.glsl).
    uint vertex_stride;    // Bytes between vertices (include/geometry.glsl).
    uint index_type;       // GEOMETRY_INDEX_* (include/geometry.glsl).
    uint base_vertex;      // Added to every index (include/geometry.glsl).
    uint geometry_pad;     // Padding.
    uint64_t ids;       // Address of the triangle ids of the records.
    uint64_t nodes;     // Address of the nodes.
    uint64_t count;     // Number of nodes.
} pc;

#include "geometry.glsl"

void main() {
    uint tile = gl_WorkGroupSize.x * ITEMS;
    uint tiles = tile_count(pc.count, tile);
    for (uint t = gl_WorkGroupID.x; t < tiles; t += gl_NumWorkGroups.x) {
        uint64_t base = uint64_t(t) * uint64_t(tile) + gl_LocalInvocationID.x;
        for (uint j = 0u; j < ITEMS; ++j) {
            uint64_t k = base + uint64_t(j * gl_WorkGroupSize.x);
            if (k >= pc.count) continue;
            BvhNodeRef r = bvh_node(pc.nodes, uint(k));
            uint rc = r.node.right_or_count;
            if ((rc & BVH_LEAF_FLAG) == 0u) continue;
            uint first = r.node.left_or_first;
            uint n = rc & ~BVH_LEAF_FLAG;
            vec3 lo = vec3(uintBitsToFloat(0x7f800000u));
            vec3 hi = -lo;
            for (uint q = 0u; q < n; ++q) {
                u64vec3 tri = geometry_triangle(uint64_t(ld_u32(pc.ids, uint64_t(first + q))));
                vec3 v0 = geometry_vertex(tri.x);
                vec3 v1 = geometry_vertex(tri.y);
                vec3 v2 = geometry_vertex(tri.z);
                lo = min(lo, min(min(v0, v1), v2));
                hi = max(hi, max(max(v0, v1), v2));
            }
            r.node.min = lo;
            r.node.max = hi;
        }
    }
}
