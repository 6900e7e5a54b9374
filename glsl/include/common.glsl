// Shared GLSL of the meshchar kernels: extensions, device-address access, total-order float bits, tile loops.
//
// Every kernel addresses its arrays through 64-bit buffer device addresses passed in push constants, so no array is
// limited by maxStorageBufferRange, and computes element addresses in 64 bits (an element index may exceed 2^31).
// Work is split in tiles of gl_WorkGroupSize.x * ITEMS elements; workgroup w handles tiles w, w + G, w + 2G, ...
// where G = gl_NumWorkGroups.x, so any count is covered whatever the device's dispatch limit.
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#extension GL_EXT_shader_atomic_int64 : require
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_KHR_shader_subgroup_ballot : require

layout(buffer_reference, std430, buffer_reference_align = 4) buffer F32Ref { float v; };
layout(buffer_reference, std430, buffer_reference_align = 4) buffer U32Ref { uint v; };
layout(buffer_reference, std430, buffer_reference_align = 8) buffer U64Ref { uint64_t v; };
layout(buffer_reference, std430, buffer_reference_align = 4) buffer Vec3Ref { float x; float y; float z; };
layout(buffer_reference, std430, buffer_reference_align = 4) buffer UVec3Ref { uint a; uint b; uint c; };

float ld_f32(uint64_t base, uint64_t i) { return F32Ref(base + 4ul * i).v; }
uint ld_u32(uint64_t base, uint64_t i) { return U32Ref(base + 4ul * i).v; }
uint64_t ld_u64(uint64_t base, uint64_t i) { return U64Ref(base + 8ul * i).v; }
void st_f32(uint64_t base, uint64_t i, float x) { F32Ref(base + 4ul * i).v = x; }
void st_u32(uint64_t base, uint64_t i, uint x) { U32Ref(base + 4ul * i).v = x; }
void st_u64(uint64_t base, uint64_t i, uint64_t x) { U64Ref(base + 8ul * i).v = x; }
vec3 ld_vec3(uint64_t base, uint64_t i) {
    Vec3Ref r = Vec3Ref(base + 12ul * i);
    return vec3(r.x, r.y, r.z);
}
uvec3 ld_uvec3(uint64_t base, uint64_t i) {
    UVec3Ref r = UVec3Ref(base + 12ul * i);
    return uvec3(r.a, r.b, r.c);
}
void st_vec3(uint64_t base, uint64_t i, vec3 v) {
    Vec3Ref r = Vec3Ref(base + 12ul * i);
    r.x = v.x;
    r.y = v.y;
    r.z = v.z;
}

// IEEE total order as unsigned order (-0.0 < +0.0), the same map as keys::ordered_bits on the host.
uint ordered_bits(float x) {
    uint b = floatBitsToUint(x);
    return (b & 0x80000000u) != 0u ? ~b : (b | 0x80000000u);
}

// Number of tiles of `tile` elements covering `count` elements.
uint tile_count(uint64_t count, uint tile) { return uint((count + uint64_t(tile) - 1ul) / uint64_t(tile)); }
