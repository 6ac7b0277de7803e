// SPDX-License-Identifier: Apache-2.0
// Cluster templates the way an engine streaming instanced geometry keeps them: one template
// per quad, placed at addresses the host chose (explicit destinations), and a second command
// that reads the templates by those addresses (instantiate, or get template indices).
#pragma once

#include "bug_gpu.h"

namespace bug_programs {

// One command over `count` templates or results: its info, limits and buffers.
struct TemplateStep {
    VkClusterAccelerationStructureTriangleClusterInputNV limits{};
    VkClusterAccelerationStructureCommandsInfoNV info{};
    Buffer infos, count, objects, addresses, scratch;
    VkDeviceSize slot = 0;  // explicit destinations: the bytes each object's place spans
};

inline void start_step(Gpu& gpu, const Quads& q, VkClusterAccelerationStructureOpTypeNV op,
                       uint32_t info_size, TemplateStep& step) {
    step.limits = {VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV};
    step.limits.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    step.limits.maxClusterUniqueGeometryCount = 1;
    step.limits.maxClusterTriangleCount = 2;
    step.limits.maxClusterVertexCount = 4;
    step.limits.maxTotalTriangleCount = 2 * q.count;
    step.limits.maxTotalVertexCount = 4 * q.count;
    VkClusterAccelerationStructureCommandsInfoNV& info = step.info;
    info = {VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV};
    info.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    info.input.maxAccelerationStructureCount = q.count;
    info.input.opType = op;
    info.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    info.input.opInput.pTriangleClusters = &step.limits;
    const VkAccelerationStructureBuildSizesInfoKHR sizes = sizes_of(gpu, info.input);
    step.infos = gpu.buffer(VkDeviceSize(info_size) * q.count);
    step.count = gpu.buffer(sizeof(uint32_t));
    step.objects = gpu.buffer(sizes.accelerationStructureSize);
    step.addresses = gpu.buffer(sizeof(VkDeviceAddress) * q.count);
    step.scratch = gpu.buffer(sizes.buildScratchSize);
    std::memcpy(step.count.host, &q.count, sizeof q.count);
    info.dstImplicitData = step.objects.address;
    info.scratchData = step.scratch.address;
    info.dstAddressesArray = {step.addresses.address, sizeof(VkDeviceAddress),
                              sizeof(VkDeviceAddress) * q.count};
    info.srcInfosArray = {step.infos.address, info_size, VkDeviceSize(info_size) * q.count};
    info.srcInfosCount = step.count.address;
}

// The templates of every quad (with positions), each at an address the host chose.
// `step` must not move after this returns.
inline void prepare_template_build(Gpu& gpu, const Quads& q, TemplateStep& step) {
    using Info = VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV;
    start_step(gpu, q, VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV,
               sizeof(Info), step);
    auto* infos = reinterpret_cast<Info*>(step.infos.host);
    for (uint32_t c = 0; c < q.count; ++c) {
        const VkClusterAccelerationStructureBuildTriangleClusterInfoNV quad = quad_info(q, c);
        Info& t = infos[c];
        t = {};
        t.clusterID = quad.clusterID;
        t.triangleCount = quad.triangleCount;
        t.vertexCount = quad.vertexCount;
        t.indexType = quad.indexType;
        t.indexBufferStride = quad.indexBufferStride;
        t.vertexBufferStride = quad.vertexBufferStride;
        t.indexBuffer = quad.indexBuffer;
        t.vertexBuffer = quad.vertexBuffer;
    }
    step.slot = place_explicitly(gpu, step.info, step.addresses, q.count,
                                 gpu.cluster_props.clusterTemplateByteAlignment);
}

inline VkDeviceAddress template_address(const TemplateStep& templates, uint32_t c) {
    return reinterpret_cast<const VkDeviceAddress*>(templates.addresses.host)[c];
}

// One instantiation of every template, each over its quad's vertices moved up by 5.
inline void prepare_instantiation(Gpu& gpu, const Quads& q, const TemplateStep& templates,
                                  TemplateStep& step) {
    using Info = VkClusterAccelerationStructureInstantiateClusterInfoNV;
    start_step(gpu, q, VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV,
               sizeof(Info), step);
    auto* infos = reinterpret_cast<Info*>(step.infos.host);
    for (uint32_t c = 0; c < q.count; ++c) {
        infos[c] = {};
        infos[c].clusterIdOffset = 1000;
        infos[c].clusterTemplateAddress = template_address(templates, c);
        infos[c].vertexBuffer = {quad_info(q, c).vertexBuffer, 3 * sizeof(float)};
    }
}

// The template indices of every template.
inline void prepare_template_indices(Gpu& gpu, const Quads& q, const TemplateStep& templates,
                                     TemplateStep& step) {
    using Info = VkClusterAccelerationStructureGetTemplateIndicesInfoNV;
    start_step(gpu, q, VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV,
               sizeof(Info), step);
    auto* infos = reinterpret_cast<Info*>(step.infos.host);
    for (uint32_t c = 0; c < q.count; ++c)
        infos[c].clusterTemplateAddress = template_address(templates, c);
}

}  // namespace bug_programs
