#version 460
// The animation of examples/engine_frame.rs: an engine's own kernel, not one of meshchar's (the example creates its
// pipeline with ash). It moves one mesh of an interleaved vertex buffer (position at byte 0, normal at byte 12 of
// every vertex) from a rest copy of the same layout, for frame `time`:
//   rotate  (mode 0): every vertex of the mesh turns by `angle * time` radians about the unit axis through
//                     `center` (Rodrigues' formula); its normal turns with it. One invocation per vertex.
//   explode (mode 1): every triangle moves along the unit normal of its rest triangle by
//                     `time * speed * (0.005 + 0.015 u)`, u in [0, 1) a hash of the triangle number and `seed` (as
//                     meshchar::mesh::generate::explode, which draws u from its generator); a zero-area triangle
//                     moves along +y. One invocation per triangle, which writes its three vertices: the mesh must be
//                     a triangle soup (no vertex shared by two triangles), or shared vertices get one of the moves.
// Only positions (and, rotating, normals) are written; uvs are left alone. Vertices are read and written through
// buffer device addresses; every index is relative to `first_vertex`.
#include "common.glsl"

layout(local_size_x_id = 0) in;

layout(push_constant) uniform Push {
    uint64_t rest;      // Address of vertex 0 of the rest copy (same layout as `live`).
    uint64_t live;      // Address of vertex 0 of the animated vertex buffer.
    uint64_t indices;   // Explode: address of the mesh's first index.
    uint first_vertex;  // The mesh's first vertex in both buffers.
    uint count;         // Rotate: vertices of the mesh; explode: its triangles.
    uint stride;        // Bytes between vertices (a multiple of 4, at least 24).
    uint mode;          // 0: rotate, 1: explode.
    uint index_bytes;   // Explode: 2 for 16-bit, 4 for 32-bit indices.
    uint seed;          // Explode: the speed hash's seed.
    float time;         // Frame number (0: the rest pose).
    float speed;        // Explode: distance per frame at u = 0 is 0.005 speed (the diagonal of the rest bounds).
    float angle;        // Rotate: radians per frame.
    float axis_x;       // Rotate: the unit axis, x.
    float axis_y;       // Rotate: the unit axis, y.
    float axis_z;       // Rotate: the unit axis, z.
    float center_x;     // Rotate: a point of the axis, x.
    float center_y;     // Rotate: a point of the axis, y.
    float center_z;     // Rotate: a point of the axis, z.
    uint pad;           // Padding.
} pc;

uint64_t vertex_at(uint64_t base, uint v) { return base + uint64_t(pc.first_vertex + v) * uint64_t(pc.stride); }

vec3 load3(uint64_t at) {
    Vec3Ref r = Vec3Ref(at);
    return vec3(r.x, r.y, r.z);
}

void store3(uint64_t at, vec3 v) {
    Vec3Ref r = Vec3Ref(at);
    r.x = v.x;
    r.y = v.y;
    r.z = v.z;
}

uint index_at(uint i) {
    if (pc.index_bytes == 4u) {
        return ld_u32(pc.indices, uint64_t(i));
    }
    uint64_t at = pc.indices + 2ul * uint64_t(i);
    uint w = U32Ref(at & ~3ul).v;
    return (at & 2ul) != 0ul ? (w >> 16) : (w & 0xffffu);
}

// PCG hash (Jarzynski and Olano 2020).
uint pcg(uint v) {
    uint state = v * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

vec3 rotate(vec3 v, vec3 k, float c, float s) { return v * c + cross(k, v) * s + k * (dot(k, v) * (1.0 - c)); }

void main() {
    uint threads = gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    for (uint i = gl_GlobalInvocationID.x; i < pc.count; i += threads) {
        if (pc.mode == 0u) {
            vec3 k = vec3(pc.axis_x, pc.axis_y, pc.axis_z);
            vec3 o = vec3(pc.center_x, pc.center_y, pc.center_z);
            float a = pc.angle * pc.time;
            float c = cos(a);
            float s = sin(a);
            uint64_t from = vertex_at(pc.rest, i);
            uint64_t to = vertex_at(pc.live, i);
            store3(to, o + rotate(load3(from) - o, k, c, s));
            store3(to + 12ul, rotate(load3(from + 12ul), k, c, s));
        } else {
            uint i0 = index_at(3u * i);
            uint i1 = index_at(3u * i + 1u);
            uint i2 = index_at(3u * i + 2u);
            vec3 a = load3(vertex_at(pc.rest, i0));
            vec3 b = load3(vertex_at(pc.rest, i1));
            vec3 c = load3(vertex_at(pc.rest, i2));
            vec3 n = cross(b - a, c - a);
            float len = length(n);
            vec3 dir = len > 0.0 ? n / len : vec3(0.0, 1.0, 0.0);
            float u = float(pcg(i ^ pcg(pc.seed)) >> 8) * (1.0 / 16777216.0);
            vec3 d = dir * (pc.time * pc.speed * (0.005 + 0.015 * u));
            store3(vertex_at(pc.live, i0), a + d);
            store3(vertex_at(pc.live, i1), b + d);
            store3(vertex_at(pc.live, i2), c + d);
        }
    }
}
