#version 460
// Triangle records (include/trace.glsl, TriRecord) of a device-built BVH for the traversal kernel: record r is
// triangle ids[r] of the geometry view (triangle r when `ids` is 0), as geom::Triangle::new makes it on the host:
// v0, e1 = v1 - v0, e2 = v2 - v0 in f32, both edges zero when the edges' cross product is exactly zero in f64
// (a zero-area triangle), and the mesh index.
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#include "common.glsl"
#include "trace.glsl"

layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint ITEMS = 4;

layout(push_constant) uniform Push {
    uint64_t positions;    // Address of the position of vertex 0 (include/geometry.glsl).
    uint64_t indices;      // Address of the first index (include/geometry.glsl).
    uint64_t vertex_count; // Vertices of the view (include/geometry.glsl).
    uint vertex_stride;    // Bytes between vertices (include/geometry.glsl).
    uint index_type;       // GEOMETRY_INDEX_* (include/geometry.glsl).
    uint base_vertex;      // Added to every index (include/geometry.glsl).
    uint geometry_pad;     // Padding.
    uint64_t ids;     // Address of the mesh index of every record, or 0 for records in mesh order.
    uint64_t records; // Address of the output TriRecord array.
    uint64_t count;   // Records.
} pc;

#include "geometry.glsl"

layout(buffer_reference, std430, buffer_reference_align = 16) writeonly buffer TriRecordOut { TriRecord rec; };

void main() {
    uint tile = gl_WorkGroupSize.x * ITEMS;
    uint tiles = tile_count(pc.count, tile);
    for (uint t = gl_WorkGroupID.x; t < tiles; t += gl_NumWorkGroups.x) {
        uint64_t base = uint64_t(t) * uint64_t(tile) + gl_LocalInvocationID.x;
        for (uint j = 0u; j < ITEMS; ++j) {
            uint64_t k = base + uint64_t(j * gl_WorkGroupSize.x);
            if (k >= pc.count) continue;
            uint id = pc.ids == 0ul ? uint(k) : ld_u32(pc.ids, k);
            u64vec3 v = geometry_triangle(uint64_t(id));
            vec3 a = geometry_vertex(v.x);
            vec3 b = geometry_vertex(v.y);
            vec3 c = geometry_vertex(v.z);
            precise dvec3 p = dvec3(b) - dvec3(a);
            precise dvec3 q = dvec3(c) - dvec3(a);
            precise dvec3 n = dvec3(p.y * q.z - q.y * p.z, p.z * q.x - q.z * p.x, p.x * q.y - q.x * p.y);
            precise double len2 = (n.x * n.x + n.y * n.y) + n.z * n.z;
            TriRecord r;
            r.v0 = a;
            r.id = id;
            precise vec3 e1 = b - a;
            precise vec3 e2 = c - a;
            r.e1 = len2 == 0.0lf ? vec3(0.0) : e1;
            r.pad_a = 0u;
            r.e2 = len2 == 0.0lf ? vec3(0.0) : e2;
            r.pad_b = 0u;
            TriRecordOut(pc.records + 48ul * k).rec = r;
        }
    }
}
