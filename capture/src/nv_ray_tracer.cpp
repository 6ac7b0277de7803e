// SPDX-License-Identifier: Apache-2.0
#include "clastrace/capture/nv_ray_tracer.h"

#include "ray_check_session.h"

#include <cstring>

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

using namespace ray_check;

constexpr VkShaderStageFlags kStages = VK_SHADER_STAGE_RAYGEN_BIT_NV | VK_SHADER_STAGE_MISS_BIT_NV |
                                       VK_SHADER_STAGE_CLOSEST_HIT_BIT_NV |
                                       VK_SHADER_STAGE_INTERSECTION_BIT_NV;

VkDeviceSize align_up(VkDeviceSize value, VkDeviceSize alignment) {
    return alignment ? (value + alignment - 1) / alignment * alignment : value;
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

bool record_trace_rays(Session& s, VkCommandBuffer cb, VkPipeline pipeline,
                       VkPipelineLayout pipeline_layout, VkDescriptorSet set,
                       const ShaderBindingTable& sbt, uint32_t ray_count) {
    return record_ray_check(s, cb, VK_PIPELINE_BIND_POINT_RAY_TRACING_NV,
                            VK_PIPELINE_STAGE_RAY_TRACING_SHADER_BIT_NV, pipeline, pipeline_layout,
                            set, [&] {
                                const VkBuffer table = sbt.buffer.buffer;
                                s.f.CmdTraceRaysNV(cb, table, 0, table, sbt.miss_offset,
                                                   sbt.handle_size, table, sbt.hit_offset,
                                                   sbt.hit_stride, VK_NULL_HANDLE, 0, 0, ray_count,
                                                   1, 1);
                            });
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
    if (!s.f.CreateRayTracingPipelinesNV || !s.f.GetRayTracingShaderGroupHandlesNV ||
        !s.f.CmdTraceRaysNV) {
        s.error = "the device has no VK_NV_ray_tracing functions";
        return fail();
    }
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
    VkWriteDescriptorSetAccelerationStructureNV as_write{
        VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET_ACCELERATION_STRUCTURE_NV};
    as_write.accelerationStructureCount = 1;
    as_write.pAccelerationStructures = &top_level;
    if (!create_ray_check_layout(s, kStages, VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_NV, 0,
                                 layout) ||
        !create_ray_check_pipeline(s, layout.pipeline_layout, pipeline) ||
        !write_shader_binding_table(s, pipeline, scene, sbt) ||
        !upload_ray_check_buffers(s, scene, rays, buffers) ||
        !write_descriptor_set(s, layout.set_layout,
                              {VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_NV, &as_write}, buffers,
                              set) ||
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
