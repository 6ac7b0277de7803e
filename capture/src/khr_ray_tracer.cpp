// SPDX-License-Identifier: Apache-2.0
#include "clastrace/capture/khr_ray_tracer.h"

#include "ray_check_session.h"

#include <cstring>

// SPIR-V compiled from capture/shaders at build time (glslangValidator --vn).
#include "ray_check_comp.h"

namespace clastrace::capture {

const char* const kKhrRayCheckRule =
    "clastrace-ray-check/1 (ray query): rayQueryInitializeEXT(flags, mask); non-opaque triangle "
    "candidates confirmed; triangles: the driver's intersection, hit_kind 0xFE front / 0xFF back, "
    "barycentrics (u, v); AABB candidates: slab test in object space against the primitive's box, "
    "t = max(entry, t_min) generated if t <= exit and t <= the committed t, hit_kind 0, "
    "(u, v) = 0; closest committed hit kept";

namespace {

using namespace ray_check;

constexpr uint32_t kGroupSize = 64;  // local_size_x of ray_check.comp

bool create_ray_query_pipeline(Session& s, VkPipelineLayout pipeline_layout, VkPipeline& out) {
    VkShaderModule module;
    if (!s.shader(kRayCheck_comp, sizeof kRayCheck_comp, module)) return false;
    VkComputePipelineCreateInfo info{VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO};
    info.stage.sType = VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO;
    info.stage.stage = VK_SHADER_STAGE_COMPUTE_BIT;
    info.stage.module = module;
    info.stage.pName = "main";
    info.layout = pipeline_layout;
    info.basePipelineIndex = -1;
    VkPipeline pipeline;
    if (!s.check(s.f.CreateComputePipelines(s.device(), VK_NULL_HANDLE, 1, &info, nullptr,
                                            &pipeline),
                 "vkCreateComputePipelines"))
        return false;
    s.cleanup.push_back([&s, pipeline] { s.f.DestroyPipeline(s.device(), pipeline, nullptr); });
    out = pipeline;
    return true;
}

bool record_ray_queries(Session& s, VkCommandBuffer cb, VkPipeline pipeline,
                        VkPipelineLayout pipeline_layout, VkDescriptorSet set, uint32_t ray_count) {
    return record_ray_check(s, cb, VK_PIPELINE_BIND_POINT_COMPUTE,
                            VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, pipeline, pipeline_layout, set,
                            [&] {
                                s.f.CmdPushConstants(cb, pipeline_layout,
                                                     VK_SHADER_STAGE_COMPUTE_BIT, 0,
                                                     sizeof ray_count, &ray_count);
                                s.f.CmdDispatch(cb, (ray_count + kGroupSize - 1) / kGroupSize, 1,
                                                1);
                            });
}

}  // namespace

bool trace_rays_khr(const NvRayTracerContext& context, VkAccelerationStructureKHR top_level,
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
    if (!s.f.CreateComputePipelines || !s.f.CmdDispatch || !s.f.CmdPushConstants) {
        s.error = "the device has no compute pipeline functions";
        return fail();
    }
    RayCheckLayout layout;
    VkPipeline pipeline;
    RayCheckBuffers buffers;
    VkDescriptorSet set;
    VkCommandBuffer cb;
    VkWriteDescriptorSetAccelerationStructureKHR as_write{
        VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET_ACCELERATION_STRUCTURE_KHR};
    as_write.accelerationStructureCount = 1;
    as_write.pAccelerationStructures = &top_level;
    if (!create_ray_check_layout(s, VK_SHADER_STAGE_COMPUTE_BIT,
                                 VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_KHR, sizeof(uint32_t),
                                 layout) ||
        !create_ray_query_pipeline(s, layout.pipeline_layout, pipeline) ||
        !upload_ray_check_buffers(s, scene, rays, buffers) ||
        !write_descriptor_set(s, layout.set_layout,
                              {VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_KHR, &as_write}, buffers,
                              set) ||
        !allocate_command_buffer(s, cb) ||
        !record_ray_queries(s, cb, pipeline, layout.pipeline_layout, set, uint32_t(rays.size())) ||
        !submit_and_wait(s, cb))
        return fail();
    hits.resize(rays.size());
    std::memcpy(hits.data(), buffers.hits.mapped, rays.size() * sizeof(NvRayHit));
    return true;
}

}  // namespace clastrace::capture
