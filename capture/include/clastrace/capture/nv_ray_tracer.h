// SPDX-License-Identifier: Apache-2.0
// Traces a list of rays against a VkAccelerationStructureNV top level with a small embedded
// VK_NV_ray_tracing pipeline (capture/shaders/ray_check.*), and returns the driver's answers.
// Used by the layer's ray check (CLASTRACE_RAY_CHECK) through the driver chain below it, and by
// tests/apps/nv_ray_tracing_app through the loader: both trace with the same shaders.
//
// AABB geometries need their boxes on the device (the intersection shader tests them itself,
// so the answer does not depend on how conservative the driver's box culling is): the scene
// tables say, per instance and per geometry, where they are.
#pragma once

#include <vulkan/vulkan.h>

#include <cstdint>
#include <string>
#include <vector>

namespace clastrace::capture {

// 48 bytes each: the layout the shaders read and write (std430).
struct NvTracedRay {
    float origin[3];
    float t_min;
    float direction[3];
    float t_max;
    uint32_t ray_flags;
    uint32_t cull_mask;
    uint32_t pad[2];
};
struct NvRayHit {
    uint32_t hit;  // 0 miss, 1 hit
    float t;
    uint32_t instance_custom_index;
    uint32_t instance_id;
    uint32_t primitive_id;
    uint32_t geometry_index;
    uint32_t hit_kind;
    float u, v;
    uint32_t pad[3];
};
static_assert(sizeof(NvTracedRay) == 48 && sizeof(NvRayHit) == 48);

// What the hit shaders need to know of the top level's contents.
struct NvTraceScene {
    struct Instance {
        uint32_t sbt_record_offset = 0;    // instanceShaderBindingTableRecordOffset
        uint32_t first_geometry_slot = 0;  // its bottom level's geometry 0 in `geometryIsAabb`
    };
    std::vector<Instance> instances;        // in instance-record order (gl_InstanceID)
    std::vector<uint8_t> geometry_is_aabb;  // per geometry slot
    std::vector<uint32_t>
        geometry_first_box;    // per geometry slot: first box in `boxes` (AABB slots)
    std::vector<float> boxes;  // 6 floats per box
    // Hit record r (= instance offset + geometry index) is procedural when its geometry is AABBs;
    // the layer fills it from the slots, rejecting scenes where one record serves both kinds.
    std::vector<uint8_t> record_is_procedural;
};

// The device functions the tracer calls, loaded from `getDeviceProcAddr` (the loader's for an
// application; the next layer's for the capture layer, so its own work is not intercepted).
struct NvRayTracerContext {
    VkDevice device = VK_NULL_HANDLE;
    VkQueue queue = VK_NULL_HANDLE;
    uint32_t queue_family_index = 0;
    PFN_vkGetDeviceProcAddr get_device_proc_addr = nullptr;
    VkPhysicalDeviceMemoryProperties memory_properties{};
    VkPhysicalDeviceRayTracingPropertiesNV ray_tracing_properties{};
    // Command buffers the layer allocates below the loader need the device's dispatch pointer.
    bool set_command_buffer_dispatch = false;
};

// Traces `rays` against `topLevel` after every earlier command on `queue` (a full barrier
// leads the command buffer) and waits for the answers (up to 10 s). False + `error` on any
// failure; nothing is left allocated either way.
bool trace_rays_nv(const NvRayTracerContext& context, VkAccelerationStructureNV top_level,
                   const NvTraceScene& scene, const std::vector<NvTracedRay>& rays,
                   std::vector<NvRayHit>& hits, std::string& error);

// The rule the intersection shader applies, written out for the label of a RayQueryCheck.
extern const char* const kNvRayCheckRule;

}  // namespace clastrace::capture
