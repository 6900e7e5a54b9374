#version 460
// Primary rays on the device: ray x + width * y is the ray of trace::Camera::ray for pixel (x, y) of a width x height
// image, bit for bit (the same operations in the same order, no contraction, the division and the square root of
// the normalization rounded correctly through f64), so a primary workload is never uploaded.
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#include "common.glsl"
#include "trace.glsl"

layout(local_size_x_id = 0) in;

layout(push_constant) uniform Push {
    vec4 eye;       // Eye position (xyz); w: tan(fov_y / 2).
    vec4 forward;   // Unit viewing direction (xyz).
    vec4 right;     // Unit right vector (xyz).
    vec4 up;        // Unit up vector (xyz).
    uint64_t rays;  // Address of the output TraceRay array (width * height rays, row by row).
    uint width;     // Image width (0 counts as 1 in the arithmetic, as on the host).
    uint height;    // Image height (likewise).
} pc;

layout(buffer_reference, std430, buffer_reference_align = 16) writeonly buffer TraceRayOut { TraceRay ray; };

void main() {
    uint64_t count = uint64_t(pc.width) * uint64_t(pc.height);
    uint64_t stride = uint64_t(gl_NumWorkGroups.x) * uint64_t(gl_WorkGroupSize.x);
    float w = float(max(pc.width, 1u));
    float h = float(max(pc.height, 1u));
    float aspect = div_rn(w, h);
    float thf = pc.eye.w;
    for (uint64_t k = uint64_t(gl_GlobalInvocationID.x); k < count; k += stride) {
        uint x = uint(k % uint64_t(pc.width));
        uint y = uint(k / uint64_t(pc.width));
        float u = div_rn(f_add(float(x), 0.5), w);
        float sx = f_mul(f_mul(f_sub(f_mul(u, 2.0), 1.0), thf), aspect);
        float v = div_rn(f_add(float(y), 0.5), h);
        float sy = f_mul(f_sub(1.0, f_mul(v, 2.0)), thf);
        vec3 d = v_add(v_add(pc.forward.xyz, v_scale(pc.right.xyz, sx)), v_scale(pc.up.xyz, sy));
        float len = sqrt_rn(dot3(d, d));
        d = v_scale(d, div_rn(1.0, len));
        TraceRay r;
        r.origin = pc.eye.xyz;
        r.tmin = 0.0;
        r.dir = d;
        r.tmax = uintBitsToFloat(0x7f800000u);
        TraceRayOut(pc.rays + 32ul * k).ray = r;
    }
}
