// SPDX-License-Identifier: Apache-2.0
#include "clastrace/capture/nv_ray_tracer.h"

#include <cstring>
#include <functional>

// SPIR-V compiled from capture/shaders at build time (glslangValidator --vn).
#include "ray_check_rchit.h"
#include "ray_check_rgen.h"
#include "ray_check_rint.h"
#include "ray_check_rmiss.h"

namespace clastrace::capture {

const char* const kNvRayCheckRule =
    "clastrace-ray-check/1: traceNV(flags, mask, sbt offset 0, stride 1, miss 0); triangles: the "
    "driver's "
    "intersection, hit_kind 0xFE front / 0xFF back, barycentrics (u, v); AABBs: intersection "
    "shader slab test "
    "in object space against the primitive's box, t = max(entry, t_min) if t <= exit, hit_kind 0, "
    "(u, v) = 0; "
    "closest hit kept; no any-hit shader";

namespace {

#define CLASTRACE_TRACER_FUNCTIONS(X)    \
    X(CreateDescriptorSetLayout)         \
    X(DestroyDescriptorSetLayout)        \
    X(CreatePipelineLayout)              \
    X(DestroyPipelineLayout)             \
    X(CreateShaderModule)                \
    X(DestroyShaderModule)               \
    X(CreateRayTracingPipelinesNV)       \
    X(DestroyPipeline)                   \
    X(GetRayTracingShaderGroupHandlesNV) \
    X(CreateBuffer)                      \
    X(DestroyBuffer)                     \
    X(GetBufferMemoryRequirements)       \
    X(AllocateMemory)                    \
    X(FreeMemory)                        \
    X(BindBufferMemory)                  \
    X(MapMemory)                         \
    X(CreateDescriptorPool)              \
    X(DestroyDescriptorPool)             \
    X(AllocateDescriptorSets)            \
    X(UpdateDescriptorSets)              \
    X(CreateCommandPool)                 \
    X(DestroyCommandPool)                \
    X(AllocateCommandBuffers)            \
    X(BeginCommandBuffer)                \
    X(EndCommandBuffer)                  \
    X(CmdPipelineBarrier)                \
    X(CmdBindPipeline)                   \
    X(CmdBindDescriptorSets)             \
    X(CmdTraceRaysNV)                    \
    X(CreateFence)                       \
    X(DestroyFence)                      \
    X(QueueSubmit)                       \
    X(WaitForFences)

struct Functions {
#define CLASTRACE_DECLARE(name) PFN_vk##name name = nullptr;
    CLASTRACE_TRACER_FUNCTIONS(CLASTRACE_DECLARE)
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
    VkDevice device() const { return context.device; }

    bool load() {
#define CLASTRACE_LOAD(name)                                                         \
    f.name = (PFN_vk##name)context.get_device_proc_addr(context.device, "vk" #name); \
    if (!f.name) {                                                                   \
        error = "the device has no vk" #name;                                        \
        return false;                                                                \
    }
        CLASTRACE_TRACER_FUNCTIONS(CLASTRACE_LOAD)
#undef CLASTRACE_LOAD
        return true;
    }

    bool check(VkResult result, const char* what) {
        if (result == VK_SUCCESS) return true;
        error = std::string(what) + " failed with VkResult " + std::to_string(int(result));
        return false;
    }

    bool host_buffer(VkDeviceSize size, VkBufferUsageFlags usage, HostBuffer& out) {
        out.size = size ? size : 16;
        VkBufferCreateInfo info{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO};
        info.size = out.size;
        info.usage = usage;
        info.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
        if (!check(f.CreateBuffer(device(), &info, nullptr, &out.buffer), "vkCreateBuffer"))
            return false;
        VkBuffer buffer = out.buffer;
        cleanup.push_back([this, buffer] { f.DestroyBuffer(device(), buffer, nullptr); });
        VkMemoryRequirements requirements;
        f.GetBufferMemoryRequirements(device(), out.buffer, &requirements);
        const VkMemoryPropertyFlags wanted =
            VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
        uint32_t type = UINT32_MAX;
        for (uint32_t i = 0; i < context.memory_properties.memoryTypeCount && type == UINT32_MAX;
             ++i)
            if ((requirements.memoryTypeBits & (1u << i)) &&
                (context.memory_properties.memoryTypes[i].propertyFlags & wanted) == wanted)
                type = i;
        if (type == UINT32_MAX) {
            error = "no host-visible coherent memory type for the ray check's buffers";
            return false;
        }
        VkMemoryAllocateInfo allocate{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO};
        allocate.allocationSize = requirements.size;
        allocate.memoryTypeIndex = type;
        if (!check(f.AllocateMemory(device(), &allocate, nullptr, &out.memory), "vkAllocateMemory"))
            return false;
        VkDeviceMemory memory = out.memory;
        cleanup.push_back(
            [this, memory] { f.FreeMemory(device(), memory, nullptr); });  // unmaps too
        if (!check(f.BindBufferMemory(device(), out.buffer, out.memory, 0), "vkBindBufferMemory"))
            return false;
        if (!check(f.MapMemory(device(), out.memory, 0, VK_WHOLE_SIZE, 0, &out.mapped),
                   "vkMapMemory"))
            return false;
        std::memset(out.mapped, 0, out.size);
        return true;
    }

    template <typename T>
    bool upload(const std::vector<T>& values, VkBufferUsageFlags usage, HostBuffer& out) {
        if (!host_buffer(values.size() * sizeof(T), usage, out)) return false;
        if (!values.empty()) std::memcpy(out.mapped, values.data(), values.size() * sizeof(T));
        return true;
    }

    bool shader(const uint32_t* code, size_t bytes, VkShaderModule& out) {
        VkShaderModuleCreateInfo info{VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO};
        info.codeSize = bytes;
        info.pCode = code;
        if (!check(f.CreateShaderModule(device(), &info, nullptr, &out), "vkCreateShaderModule"))
            return false;
        VkShaderModule module = out;
        cleanup.push_back([this, module] { f.DestroyShaderModule(device(), module, nullptr); });
        return true;
    }
};

VkDeviceSize align_up(VkDeviceSize value, VkDeviceSize alignment) {
    return alignment ? (value + alignment - 1) / alignment * alignment : value;
}

// The pipeline's resources: one descriptor set layout (top level, rays, hits, instance table,
// geometry table, boxes) and the pipeline layout over it.
struct RayCheckLayout {
    VkDescriptorSetLayout set_layout = VK_NULL_HANDLE;
    VkPipelineLayout pipeline_layout = VK_NULL_HANDLE;
};

bool create_ray_check_layout(Session& s, RayCheckLayout& out) {
    const VkShaderStageFlags stages = VK_SHADER_STAGE_RAYGEN_BIT_NV | VK_SHADER_STAGE_MISS_BIT_NV |
                                      VK_SHADER_STAGE_CLOSEST_HIT_BIT_NV |
                                      VK_SHADER_STAGE_INTERSECTION_BIT_NV;
    VkDescriptorSetLayoutBinding bindings[6];
    for (uint32_t b = 0; b < 6; ++b)
        bindings[b] = {b,
                       b == 0 ? VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_NV
                              : VK_DESCRIPTOR_TYPE_STORAGE_BUFFER,
                       1, stages, nullptr};
    VkDescriptorSetLayoutCreateInfo set_info{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO};
    set_info.bindingCount = 6;
    set_info.pBindings = bindings;
    VkDescriptorSetLayout set_layout;
    if (!s.check(s.f.CreateDescriptorSetLayout(s.device(), &set_info, nullptr, &set_layout),
                 "vkCreateDescriptorSetLayout"))
        return false;
    s.cleanup.push_back(
        [&s, set_layout] { s.f.DestroyDescriptorSetLayout(s.device(), set_layout, nullptr); });
    out.set_layout = set_layout;
    VkPipelineLayoutCreateInfo layout_info{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
    layout_info.setLayoutCount = 1;
    layout_info.pSetLayouts = &set_layout;
    VkPipelineLayout pipeline_layout;
    if (!s.check(s.f.CreatePipelineLayout(s.device(), &layout_info, nullptr, &pipeline_layout),
                 "vkCreatePipelineLayout"))
        return false;
    s.cleanup.push_back(
        [&s, pipeline_layout] { s.f.DestroyPipelineLayout(s.device(), pipeline_layout, nullptr); });
    out.pipeline_layout = pipeline_layout;
    return true;
}

// The ray-check pipeline; groups: 0 raygen, 1 miss, 2 triangles hit group, 3 procedural hit group.
bool create_ray_check_pipeline(Session& s, VkPipelineLayout pipeline_layout, VkPipeline& out) {
    VkShaderModule rgen, rmiss, rchit, rint;
    if (!s.shader(kRayCheck_rgen, sizeof kRayCheck_rgen, rgen) ||
        !s.shader(kRayCheck_rmiss, sizeof kRayCheck_rmiss, rmiss) ||
        !s.shader(kRayCheck_rchit, sizeof kRayCheck_rchit, rchit) ||
        !s.shader(kRayCheck_rint, sizeof kRayCheck_rint, rint))
        return false;
    VkPipelineShaderStageCreateInfo shader_stages[4] = {};
    const VkShaderStageFlagBits stage_bits[4] = {VK_SHADER_STAGE_RAYGEN_BIT_NV,
                                                 VK_SHADER_STAGE_MISS_BIT_NV,
                                                 VK_SHADER_STAGE_CLOSEST_HIT_BIT_NV,
                                                 VK_SHADER_STAGE_INTERSECTION_BIT_NV};
    const VkShaderModule modules[4] = {rgen, rmiss, rchit, rint};
    for (int i = 0; i < 4; ++i) {
        shader_stages[i].sType = VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO;
        shader_stages[i].stage = stage_bits[i];
        shader_stages[i].module = modules[i];
        shader_stages[i].pName = "main";
    }
    VkRayTracingShaderGroupCreateInfoNV groups[4];
    for (auto& g : groups) {
        g = {VK_STRUCTURE_TYPE_RAY_TRACING_SHADER_GROUP_CREATE_INFO_NV};
        g.generalShader = g.closestHitShader = g.anyHitShader = g.intersectionShader =
            VK_SHADER_UNUSED_NV;
    }
    groups[0].type = VK_RAY_TRACING_SHADER_GROUP_TYPE_GENERAL_NV;
    groups[0].generalShader = 0;
    groups[1].type = VK_RAY_TRACING_SHADER_GROUP_TYPE_GENERAL_NV;
    groups[1].generalShader = 1;
    groups[2].type = VK_RAY_TRACING_SHADER_GROUP_TYPE_TRIANGLES_HIT_GROUP_NV;
    groups[2].closestHitShader = 2;
    groups[3].type = VK_RAY_TRACING_SHADER_GROUP_TYPE_PROCEDURAL_HIT_GROUP_NV;
    groups[3].closestHitShader = 2;
    groups[3].intersectionShader = 3;
    VkRayTracingPipelineCreateInfoNV pipeline_info{
        VK_STRUCTURE_TYPE_RAY_TRACING_PIPELINE_CREATE_INFO_NV};
    pipeline_info.stageCount = 4;
    pipeline_info.pStages = shader_stages;
    pipeline_info.groupCount = 4;
    pipeline_info.pGroups = groups;
    pipeline_info.maxRecursionDepth = 1;
    pipeline_info.layout = pipeline_layout;
    pipeline_info.basePipelineIndex = -1;
    VkPipeline pipeline;
    if (!s.check(s.f.CreateRayTracingPipelinesNV(s.device(), VK_NULL_HANDLE, 1, &pipeline_info,
                                                 nullptr, &pipeline),
                 "vkCreateRayTracingPipelinesNV"))
        return false;
    s.cleanup.push_back([&s, pipeline] { s.f.DestroyPipeline(s.device(), pipeline, nullptr); });
    out = pipeline;
    return true;
}

// Shader binding table: raygen | miss | hit records (handle, then the record's index).
struct ShaderBindingTable {
    HostBuffer buffer;
    VkDeviceSize handle_size = 0;
    VkDeviceSize miss_offset = 0;
    VkDeviceSize hit_offset = 0;
    VkDeviceSize hit_stride = 0;
};

bool write_shader_binding_table(Session& s, VkPipeline pipeline, const NvTraceScene& scene,
                                ShaderBindingTable& out) {
    const auto& rt = s.context.ray_tracing_properties;
    const uint32_t handle_size = rt.shaderGroupHandleSize;
    std::vector<uint8_t> handles(size_t(handle_size) * 4);
    if (!s.check(s.f.GetRayTracingShaderGroupHandlesNV(s.device(), pipeline, 0, 4, handles.size(),
                                                       handles.data()),
                 "vkGetRayTracingShaderGroupHandlesNV"))
        return false;
    const VkDeviceSize base = rt.shaderGroupBaseAlignment ? rt.shaderGroupBaseAlignment : 64;
    const VkDeviceSize hit_stride = align_up(handle_size + sizeof(uint32_t), handle_size);
    if (rt.maxShaderGroupStride && hit_stride > rt.maxShaderGroupStride) {
        s.error = "hit record stride exceeds maxShaderGroupStride";
        return false;
    }
    const size_t record_count =
        scene.record_is_procedural.empty() ? 1 : scene.record_is_procedural.size();
    out.handle_size = handle_size;
    out.miss_offset = base;
    out.hit_offset = 2 * base;
    out.hit_stride = hit_stride;
    if (!s.host_buffer(out.hit_offset + hit_stride * record_count,
                       VK_BUFFER_USAGE_RAY_TRACING_BIT_NV, out.buffer))
        return false;
    auto* table = static_cast<uint8_t*>(out.buffer.mapped);
    std::memcpy(table, handles.data() + 0 * handle_size, handle_size);
    std::memcpy(table + out.miss_offset, handles.data() + 1 * handle_size, handle_size);
    for (size_t r = 0; r < record_count; ++r) {
        const bool procedural =
            r < scene.record_is_procedural.size() && scene.record_is_procedural[r];
        uint8_t* record = table + out.hit_offset + r * hit_stride;
        std::memcpy(record, handles.data() + (procedural ? 3 : 2) * handle_size, handle_size);
        const uint32_t index = uint32_t(r);
        std::memcpy(record + handle_size, &index, sizeof index);
    }
    return true;
}

// The storage buffers of bindings 1..5, in binding order.
struct RayCheckBuffers {
    HostBuffer rays, hits, instances, geometries, boxes;
};

// Uploads the rays and the per-instance and per-geometry tables the hit shaders read.
bool upload_ray_check_buffers(Session& s, const NvTraceScene& scene,
                              const std::vector<NvTracedRay>& rays, RayCheckBuffers& out) {
    std::vector<uint32_t> instance_info;
    for (const auto& i : scene.instances) {
        instance_info.push_back(i.sbt_record_offset);
        instance_info.push_back(i.first_geometry_slot);
    }
    std::vector<uint32_t> geometry_table;
    for (size_t g = 0; g < scene.geometry_is_aabb.size(); ++g)
        geometry_table.push_back(scene.geometry_is_aabb[g] && g < scene.geometry_first_box.size()
                                     ? scene.geometry_first_box[g]
                                     : 0xFFFFFFFFu);
    const VkBufferUsageFlags storage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
    return s.upload(rays, storage, out.rays) &&
           s.host_buffer(rays.size() * sizeof(NvRayHit), storage, out.hits) &&
           s.upload(instance_info, storage, out.instances) &&
           s.upload(geometry_table, storage, out.geometries) &&
           s.upload(scene.boxes, storage, out.boxes);
}

bool write_descriptor_set(Session& s, VkDescriptorSetLayout set_layout,
                          VkAccelerationStructureNV top_level, const RayCheckBuffers& buffers,
                          VkDescriptorSet& out) {
    VkDescriptorPoolSize pool_sizes[2] = {{VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_NV, 1},
                                          {VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 5}};
    VkDescriptorPoolCreateInfo pool_info{VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO};
    pool_info.maxSets = 1;
    pool_info.poolSizeCount = 2;
    pool_info.pPoolSizes = pool_sizes;
    VkDescriptorPool pool;
    if (!s.check(s.f.CreateDescriptorPool(s.device(), &pool_info, nullptr, &pool),
                 "vkCreateDescriptorPool"))
        return false;
    s.cleanup.push_back([&s, pool] { s.f.DestroyDescriptorPool(s.device(), pool, nullptr); });
    VkDescriptorSetAllocateInfo set_allocate{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO};
    set_allocate.descriptorPool = pool;
    set_allocate.descriptorSetCount = 1;
    set_allocate.pSetLayouts = &set_layout;
    VkDescriptorSet set;
    if (!s.check(s.f.AllocateDescriptorSets(s.device(), &set_allocate, &set),
                 "vkAllocateDescriptorSets"))
        return false;
    VkWriteDescriptorSetAccelerationStructureNV as_write{
        VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET_ACCELERATION_STRUCTURE_NV};
    as_write.accelerationStructureCount = 1;
    as_write.pAccelerationStructures = &top_level;
    const HostBuffer* storage_buffers[5] = {&buffers.rays, &buffers.hits, &buffers.instances,
                                            &buffers.geometries, &buffers.boxes};
    VkDescriptorBufferInfo buffer_infos[5];
    VkWriteDescriptorSet writes[6] = {};
    writes[0] = {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET,      &as_write, set, 0, 0, 1,
                 VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_NV};
    for (uint32_t b = 0; b < 5; ++b) {
        buffer_infos[b] = {storage_buffers[b]->buffer, 0, VK_WHOLE_SIZE};
        writes[b + 1] = {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET,
                         nullptr,
                         set,
                         b + 1,
                         0,
                         1,
                         VK_DESCRIPTOR_TYPE_STORAGE_BUFFER,
                         nullptr,
                         &buffer_infos[b],
                         nullptr};
    }
    s.f.UpdateDescriptorSets(s.device(), 6, writes, 0, nullptr);
    out = set;
    return true;
}

bool allocate_command_buffer(Session& s, VkCommandBuffer& out) {
    VkCommandPoolCreateInfo command_pool_info{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
    command_pool_info.flags = VK_COMMAND_POOL_CREATE_TRANSIENT_BIT;
    command_pool_info.queueFamilyIndex = s.context.queue_family_index;
    VkCommandPool command_pool;
    if (!s.check(s.f.CreateCommandPool(s.device(), &command_pool_info, nullptr, &command_pool),
                 "vkCreateCommandPool"))
        return false;
    s.cleanup.push_back(
        [&s, command_pool] { s.f.DestroyCommandPool(s.device(), command_pool, nullptr); });
    VkCommandBufferAllocateInfo cb_info{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
    cb_info.commandPool = command_pool;
    cb_info.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
    cb_info.commandBufferCount = 1;
    if (!s.check(s.f.AllocateCommandBuffers(s.device(), &cb_info, &out),
                 "vkAllocateCommandBuffers"))
        return false;
    if (s.context.set_command_buffer_dispatch)
        *reinterpret_cast<void**>(out) = *reinterpret_cast<void**>(s.device());
    return true;
}

bool record_trace_rays(Session& s, VkCommandBuffer cb, VkPipeline pipeline,
                       VkPipelineLayout pipeline_layout, VkDescriptorSet set,
                       const ShaderBindingTable& sbt, uint32_t ray_count) {
    auto& f = s.f;
    VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
    begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
    if (!s.check(f.BeginCommandBuffer(cb, &begin), "vkBeginCommandBuffer")) return false;
    // Every earlier command of the queue (the builds) completes before the rays are traced.
    const VkMemoryBarrier before{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                                 VK_ACCESS_MEMORY_WRITE_BIT,
                                 VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_NV |
                                     VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT};
    f.CmdPipelineBarrier(cb, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT,
                         VK_PIPELINE_STAGE_RAY_TRACING_SHADER_BIT_NV, 0, 1, &before, 0, nullptr, 0,
                         nullptr);
    f.CmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_RAY_TRACING_NV, pipeline);
    f.CmdBindDescriptorSets(cb, VK_PIPELINE_BIND_POINT_RAY_TRACING_NV, pipeline_layout, 0, 1, &set,
                            0, nullptr);
    const VkBuffer table = sbt.buffer.buffer;
    f.CmdTraceRaysNV(cb, table, 0, table, sbt.miss_offset, sbt.handle_size, table, sbt.hit_offset,
                     sbt.hit_stride, VK_NULL_HANDLE, 0, 0, ray_count, 1, 1);
    const VkMemoryBarrier after{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                                VK_ACCESS_SHADER_WRITE_BIT, VK_ACCESS_HOST_READ_BIT};
    f.CmdPipelineBarrier(cb, VK_PIPELINE_STAGE_RAY_TRACING_SHADER_BIT_NV,
                         VK_PIPELINE_STAGE_HOST_BIT, 0, 1, &after, 0, nullptr, 0, nullptr);
    return s.check(f.EndCommandBuffer(cb), "vkEndCommandBuffer");
}

bool submit_and_wait(Session& s, VkCommandBuffer cb) {
    VkFenceCreateInfo fence_info{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
    VkFence fence;
    if (!s.check(s.f.CreateFence(s.device(), &fence_info, nullptr, &fence), "vkCreateFence"))
        return false;
    s.cleanup.push_back([&s, fence] { s.f.DestroyFence(s.device(), fence, nullptr); });
    VkSubmitInfo submit{VK_STRUCTURE_TYPE_SUBMIT_INFO};
    submit.commandBufferCount = 1;
    submit.pCommandBuffers = &cb;
    if (!s.check(s.f.QueueSubmit(s.context.queue, 1, &submit, fence), "vkQueueSubmit"))
        return false;
    if (!s.check(s.f.WaitForFences(s.device(), 1, &fence, VK_TRUE, 10'000'000'000ull),
                 "vkWaitForFences")) {
        // The queue still owns our objects: leaking them beats freeing what the GPU may use.
        s.cleanup.clear();
        return false;
    }
    return true;
}

}  // namespace

bool trace_rays_nv(const NvRayTracerContext& context, VkAccelerationStructureNV top_level,
                   const NvTraceScene& scene, const std::vector<NvTracedRay>& rays,
                   std::vector<NvRayHit>& hits, std::string& error) {
    hits.clear();
    if (rays.empty()) return true;
    Session s(context);
    auto fail = [&] {
        error = s.error;
        return false;
    };
    if (!s.load()) return fail();
    if (context.ray_tracing_properties.shaderGroupHandleSize == 0) {
        s.error = "VkPhysicalDeviceRayTracingPropertiesNV.shaderGroupHandleSize is 0";
        return fail();
    }
    RayCheckLayout layout;
    VkPipeline pipeline;
    ShaderBindingTable sbt;
    RayCheckBuffers buffers;
    VkDescriptorSet set;
    VkCommandBuffer cb;
    if (!create_ray_check_layout(s, layout) ||
        !create_ray_check_pipeline(s, layout.pipeline_layout, pipeline) ||
        !write_shader_binding_table(s, pipeline, scene, sbt) ||
        !upload_ray_check_buffers(s, scene, rays, buffers) ||
        !write_descriptor_set(s, layout.set_layout, top_level, buffers, set) ||
        !allocate_command_buffer(s, cb) ||
        !record_trace_rays(s, cb, pipeline, layout.pipeline_layout, set, sbt,
                           uint32_t(rays.size())) ||
        !submit_and_wait(s, cb))
        return fail();
    hits.resize(rays.size());
    std::memcpy(hits.data(), buffers.hits.mapped, rays.size() * sizeof(NvRayHit));
    return true;
}

}  // namespace clastrace::capture
