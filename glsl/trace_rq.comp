#version 460
// Ray queries against a driver acceleration structure (src/accel/driver.rs): closest hit, or any hit (shadow
// rays), for the same TraceRay array as glsl/trace.comp, written as TraceHit records (triangle: the primitive
// index, which is the mesh triangle; u, v: the driver's barycentrics; no box or triangle counts: the driver exposes
// none). Every geometry is opaque, so the query needs no candidate loop. Needs VK_KHR_ray_query; created only on
// devices that have it.
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#extension GL_EXT_ray_query : require
#include "common.glsl"
#include "trace.glsl"

layout(local_size_x_id = 0) in;

layout(push_constant) uniform Push {
    uint64_t rays;  // Address of the TraceRay array.
    uint64_t hits;  // Address of the TraceHit array.
    uint64_t tlas;  // Device address of the top-level acceleration structure.
    uint64_t count; // Rays.
    uint any_hit;   // 1: any hit (the first hit found ends the query), 0: closest hit.
    uint pad;       // Padding.
} pc;

void main() {
    uint64_t invocations = uint64_t(gl_NumWorkGroups.x) * uint64_t(gl_WorkGroupSize.x);
    uint64_t g = uint64_t(gl_WorkGroupID.x) * uint64_t(gl_WorkGroupSize.x) + uint64_t(gl_LocalInvocationIndex);
    uint flags = gl_RayFlagsOpaqueEXT | (pc.any_hit != 0u ? gl_RayFlagsTerminateOnFirstHitEXT : 0u);
    for (uint64_t i = g; i < pc.count; i += invocations) {
        TraceRay ray = TraceRayRef(pc.rays + 32ul * i).ray;
        rayQueryEXT q;
        rayQueryInitializeEXT(q, accelerationStructureEXT(pc.tlas), flags, 0xffu, ray.origin, ray.tmin, ray.dir, ray.tmax);
        while (rayQueryProceedEXT(q)) {
        }
        TraceHit h;
        bool hit = rayQueryGetIntersectionTypeEXT(q, true) == gl_RayQueryCommittedIntersectionTriangleEXT;
        h.t = hit ? rayQueryGetIntersectionTEXT(q, true) : 0.0;
        h.triangle = hit ? uint(rayQueryGetIntersectionPrimitiveIndexEXT(q, true)) : TRACE_MISS;
        vec2 b = hit ? rayQueryGetIntersectionBarycentricsEXT(q, true) : vec2(0.0);
        h.u = b.x;
        h.v = b.y;
        h.box_tests = 0u;
        h.prim_tests = 0u;
        h.status = TRACE_OK;
        h.pad = 0u;
        TraceHitRef(pc.hits + 32ul * i).hit = h;
    }
}
