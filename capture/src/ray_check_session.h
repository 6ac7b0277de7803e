// SPDX-License-Identifier: Apache-2.0
// What the ray check's tracers share (nv_ray_tracer.cpp: a VK_NV_ray_tracing pipeline against an
// NV top level; khr_ray_tracer.cpp: a ray-query compute pipeline against a KHR top level): the
// device functions, one session that owns and frees every object it creates, host-visible
// buffers, the descriptor set of bindings 0..5 (top level, rays, hits, instance table, geometry
// table, boxes; capture/shaders/ray_check_common.glsl), and the submission.
#pragma once

#include "clastrace/capture/nv_ray_tracer.h"

#include <cstring>
#include <functional>
#include <string>
#include <vector>

namespace clastrace::capture::ray_check {

#define CLASTRACE_TRACER_FUNCTIONS(X) \
    X(CreateDescriptorSetLayout)      \
    X(DestroyDescriptorSetLayout)     \
    X(CreatePipelineLayout)           \
    X(DestroyPipelineLayout)          \
    X(CreateShaderModule)             \
    X(DestroyShaderModule)            \
    X(DestroyPipeline)                \
    X(CreateBuffer)                   \
    X(DestroyBuffer)                  \
    X(GetBufferMemoryRequirements)    \
    X(AllocateMemory)                 \
    X(FreeMemory)                     \
    X(BindBufferMemory)               \
    X(MapMemory)                      \
    X(CreateDescriptorPool)           \
    X(DestroyDescriptorPool)          \
    X(AllocateDescriptorSets)         \
    X(UpdateDescriptorSets)           \
    X(CreateCommandPool)              \
    X(DestroyCommandPool)             \
    X(AllocateCommandBuffers)         \
    X(BeginCommandBuffer)             \
    X(EndCommandBuffer)               \
    X(CmdPipelineBarrier)             \
    X(CmdBindPipeline)                \
    X(CmdBindDescriptorSets)          \
    X(CreateFence)                    \
    X(DestroyFence)                   \
    X(QueueSubmit)                    \
    X(WaitForFences)

// Each tracer's own: loaded when present, checked by the tracer that needs them.
#define CLASTRACE_TRACER_OPTIONAL_FUNCTIONS(X) \
    X(CreateRayTracingPipelinesNV)             \
    X(GetRayTracingShaderGroupHandlesNV)       \
    X(CmdTraceRaysNV)                          \
    X(CreateComputePipelines)                  \
    X(CmdDispatch)                             \
    X(CmdPushConstants)

struct Functions {
#define CLASTRACE_DECLARE(name) PFN_vk##name name = nullptr;
    CLASTRACE_TRACER_FUNCTIONS(CLASTRACE_DECLARE)
    CLASTRACE_TRACER_OPTIONAL_FUNCTIONS(CLASTRACE_DECLARE)
#undef CLASTRACE_DECLARE
};

struct HostBuffer {
    VkBuffer buffer = VK_NULL_HANDLE;
    VkDeviceMemory memory = VK_NULL_HANDLE;
    void* mapped = nullptr;
    VkDeviceSize size = 0;
};

// Everything one trace creates, destroyed in reverse order whatever happened.
struct Session {
    const NvRayTracerContext& context;
    Functions f;
    std::vector<std::function<void()>> cleanup;
    std::string error;

    explicit Session(const NvRayTracerContext& c) : context(c) {}
    ~Session() {
        for (auto it = cleanup.rbegin(); it != cleanup.rend(); ++it) (*it)();
    }
    Session(const Session&) = delete;
    Session& operator=(const Session&) = delete;
    VkDevice device() const { return context.device; }

    bool load();  // false + error when a function every tracer needs is missing
    bool check(VkResult result, const char* what);
    bool host_buffer(VkDeviceSize size, VkBufferUsageFlags usage, HostBuffer& out);
    template <typename T>
    bool upload(const std::vector<T>& values, VkBufferUsageFlags usage, HostBuffer& out) {
        if (!host_buffer(values.size() * sizeof(T), usage, out)) return false;
        if (!values.empty()) std::memcpy(out.mapped, values.data(), values.size() * sizeof(T));
        return true;
    }
    bool shader(const uint32_t* code, size_t bytes, VkShaderModule& out);
};

// The pipeline's resources: one descriptor set layout (top level, rays, hits, instance table,
// geometry table, boxes) and the pipeline layout over it (push constants when asked).
struct RayCheckLayout {
    VkDescriptorSetLayout set_layout = VK_NULL_HANDLE;
    VkPipelineLayout pipeline_layout = VK_NULL_HANDLE;
};
bool create_ray_check_layout(Session& s, VkShaderStageFlags stages,
                             VkDescriptorType acceleration_structure_type,
                             uint32_t push_constant_bytes, RayCheckLayout& out);

// The storage buffers of bindings 1..5, in binding order.
struct RayCheckBuffers {
    HostBuffer rays, hits, instances, geometries, boxes;
};
// Uploads the rays and the per-instance and per-geometry tables the hit shaders read.
bool upload_ray_check_buffers(Session& s, const NvTraceScene& scene,
                              const std::vector<NvTracedRay>& rays, RayCheckBuffers& out);

// Binding 0: the top level, as its API writes it (a VkWriteDescriptorSetAccelerationStructure*
// chained to the write).
struct TopLevelDescriptor {
    VkDescriptorType type;
    const void* write;
};
bool write_descriptor_set(Session& s, VkDescriptorSetLayout set_layout,
                          const TopLevelDescriptor& top_level, const RayCheckBuffers& buffers,
                          VkDescriptorSet& out);

bool allocate_command_buffer(Session& s, VkCommandBuffer& out);

// Records `cb` for one trace: a full barrier after every earlier command of the queue (the
// builds), the pipeline and set bound at `bind_point`, `trace` (the dispatch or traceRays at
// `stage`), and a barrier making the hits visible to the host.
bool record_ray_check(Session& s, VkCommandBuffer cb, VkPipelineBindPoint bind_point,
                      VkPipelineStageFlags stage, VkPipeline pipeline,
                      VkPipelineLayout pipeline_layout, VkDescriptorSet set,
                      const std::function<void()>& trace);

// Submits `cb` on the context's queue and waits up to 10 s; on a timeout the session's objects
// are leaked rather than freed under the GPU.
bool submit_and_wait(Session& s, VkCommandBuffer cb);

}  // namespace clastrace::capture::ray_check
