// SPDX-License-Identifier: Apache-2.0
#include "catalogue_scene.h"

namespace clastrace::test::catalogue {

namespace {

constexpr uint64_t kSda = VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT;
constexpr uint64_t kInput = VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
constexpr uint64_t kAsStorage = VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR;
constexpr uint64_t kStorage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
constexpr uint64_t kTransfer = VK_BUFFER_USAGE_TRANSFER_SRC_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT;

std::vector<uint8_t> geometry_bytes() {
    std::vector<uint8_t> g(0xF000, 0);
    std::vector<float> vertices;
    for (uint32_t v = 0; v < 64; ++v) {
        vertices.push_back(float(v % 2) + float(v / 4) * 3.0f);
        vertices.push_back(float((v / 2) % 2));
        vertices.push_back(0.125f * float(v % 4));
    }
    std::memcpy(g.data(), vertices.data(), vertices.size() * 4);
    // 32 triangles of one quad pattern: every index below 4.
    for (uint32_t t = 0; t < 32; ++t) {
        static constexpr uint8_t kQuad[6] = {0, 1, 2, 2, 1, 3};
        for (int k = 0; k < 3; ++k) g[0x8000 + 3 * t + k] = kQuad[(t % 2) * 3 + k];
    }
    const float bounds[6] = {-100, -100, -100, 100, 100, 100};
    std::memcpy(g.data() + 0xE000, bounds, sizeof bounds);
    return g;
}

VkClusterAccelerationStructureCommandsInfoNV command_info(
    VkClusterAccelerationStructureOpTypeNV type, Destinations mode, uint32_t count,
    uint64_t info_size) {
    VkClusterAccelerationStructureCommandsInfoNV info{};
    info.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    info.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    info.input.maxAccelerationStructureCount = count;
    info.input.opType = type;
    info.input.opMode = mode == Destinations::kImplicit
                            ? VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV
                            : VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
    info.dstImplicitData = mode == Destinations::kImplicit ? kDst : 0;
    info.scratchData = kScratch;
    info.dstAddressesArray = {kOut, 8, count * 8ull};
    if (mode == Destinations::kImplicit) info.dstSizesArray = {kSizes, 4, count * 4ull};
    info.srcInfosArray = {kInfos, info_size, count * info_size};
    return info;
}

// Explicit destinations kDst + i * kExplicitStride, as the dstAddressesArray input.
void explicit_destinations(ClusterCommand& c, uint32_t count) {
    std::vector<uint64_t> addresses;
    for (uint32_t i = 0; i < count; ++i) addresses.push_back(kDst + i * kExplicitStride);
    c.inputs.push_back({kOut, bytes_of(addresses)});
}

template <class T>
std::vector<uint8_t> infos_of(uint32_t count, T (*make)(uint32_t)) {
    std::vector<T> infos;
    for (uint32_t i = 0; i < count; ++i) infos.push_back(make(i));
    return bytes_of(infos);
}

}  // namespace

void add_buffers(TraceScript& t) {
    struct B {
        uint64_t handle, address, size, usage;
    };
    const B buffers[] = {
        {kGeometryBuffer, kGeometry, 0x10000, kSda | kInput | kStorage | kTransfer},
        {kInfosBuffer, kInfos, 0x10000, kSda | kInput | kStorage | kTransfer},
        {kDstBuffer, kDst, 0x20000, kSda | kAsStorage | kStorage | kTransfer},
        {kDst2Buffer, kDst2, 0x20000, kSda | kAsStorage | kStorage | kTransfer},
        {kOutBuffer, kOut, 0x1000, kSda | kAsStorage | kStorage | kTransfer},
        {kScratchBuffer, kScratch, 0x10000, kSda | kAsStorage | kStorage},
        {0xb007, kSmallScratch, 16, kSda | kStorage},
        {0xb008, kNoStorage, 0x10000, kSda | kInput | kAsStorage},
        {0xb009, kNoInput, 0x10000, kSda | kAsStorage | kStorage},
        {0xb00b, kNoAsStorage, 0x20000, kSda | kInput | kStorage},
        {kStagingBuffer, kStaging, 0x10000, kSda | VK_BUFFER_USAGE_TRANSFER_SRC_BIT},
    };
    for (const B& b : buffers)
        t.buffer(b.handle, b.address, b.size, b.usage, 0x1001, b.address - kBase);
}

ScriptDevice device() { return ScriptDevice{}; }

namespace {
// Cluster c of the scene: two triangles over its own four vertices, indices shared. A
// triangle cluster and a template take the same fields; only their clusterIDs differ.
template <class Info>
Info two_triangle_cluster(uint32_t cluster_id, uint32_t c) {
    Info i{};
    i.clusterID = cluster_id;
    i.triangleCount = 2;
    i.vertexCount = 4;
    i.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_8BIT_NV;
    i.indexBufferStride = 1;
    i.vertexBufferStride = 12;
    i.indexBuffer = kIndices;
    i.vertexBuffer = kVertices + c * 48ull;
    return i;
}
}  // namespace

TriangleInfo triangle_info(uint32_t c) { return two_triangle_cluster<TriangleInfo>(100 + c, c); }

TemplateInfo template_info(uint32_t c) { return two_triangle_cluster<TemplateInfo>(200 + c, c); }

VkClusterAccelerationStructureTriangleClusterInputNV triangle_input() {
    VkClusterAccelerationStructureTriangleClusterInputNV in{};
    in.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
    in.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    in.maxGeometryIndexValue = 1000;
    in.maxClusterUniqueGeometryCount = 1;
    in.maxClusterTriangleCount = 16;
    in.maxClusterVertexCount = 16;
    in.maxTotalTriangleCount = 64;
    in.maxTotalVertexCount = 64;
    return in;
}

uint32_t ClusterCommand::emit(TraceScript& t) {
    switch (info.input.opType) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV:
        info.input.opInput.pMoveObjects = &move;
        break;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV:
        info.input.opInput.pClustersBottomLevel = &bottom_level;
        break;
    default: info.input.opInput.pTriangleClusters = &triangles; break;
    }
    std::vector<InputSnapshot> all = inputs;
    if (!infos.empty()) all.push_back({infos_address, infos});
    const uint32_t index = t.next_command();
    t.cluster(info, all, driver_bvh);
    return index;
}

ClusterCommand triangle_clusters(Destinations mode, uint32_t count) {
    ClusterCommand c;
    c.info = command_info(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV, mode,
                          count, sizeof(TriangleInfo));
    c.triangles = triangle_input();
    c.infos = infos_of<TriangleInfo>(count, triangle_info);
    c.inputs.push_back({kGeometry, geometry_bytes()});
    if (mode == Destinations::kExplicit) explicit_destinations(c, count);
    return c;
}

ClusterCommand triangle_templates(Destinations mode, uint32_t count) {
    ClusterCommand c;
    c.info =
        command_info(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV,
                     mode, count, sizeof(TemplateInfo));
    c.triangles = triangle_input();
    c.infos = infos_of<TemplateInfo>(count, template_info);
    c.inputs.push_back({kGeometry, geometry_bytes()});
    if (mode == Destinations::kExplicit) explicit_destinations(c, count);
    return c;
}

ClusterCommand instantiate(uint32_t count) {
    ClusterCommand c;
    c.info = command_info(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV,
                          Destinations::kImplicit, count, sizeof(InstantiateInfo));
    c.info.dstImplicitData = kDst2;
    c.triangles = triangle_input();
    std::vector<InstantiateInfo> infos(count);
    for (uint32_t i = 0; i < count; ++i) {
        infos[i] = InstantiateInfo{};
        infos[i].clusterIdOffset = 1000 * (i + 1);
        infos[i].clusterTemplateAddress = kDst;
        infos[i].vertexBuffer = {kVertices + 48ull * i, 12};
    }
    c.infos = bytes_of(infos);
    c.inputs.push_back({kGeometry, geometry_bytes()});
    return c;
}

ClusterCommand template_indices(uint32_t count) {
    ClusterCommand c;
    c.info = command_info(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV,
                          Destinations::kImplicit, count,
                          sizeof(VkClusterAccelerationStructureGetTemplateIndicesInfoNV));
    c.info.dstImplicitData = kDst2;
    c.triangles = triangle_input();
    std::vector<VkClusterAccelerationStructureGetTemplateIndicesInfoNV> infos(count);
    for (uint32_t i = 0; i < count; ++i)
        infos[i].clusterTemplateAddress = kDst + i * kExplicitStride;
    c.infos = bytes_of(infos);
    return c;
}

ClusterCommand bottom_level(std::vector<uint64_t> references) {
    ClusterCommand c;
    c.info = command_info(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV,
                          Destinations::kImplicit, 1, sizeof(BottomLevelInfo));
    c.info.dstImplicitData = kDst2;
    c.bottom_level.sType =
        VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_CLUSTERS_BOTTOM_LEVEL_INPUT_NV;
    c.bottom_level.maxTotalClusterCount = 16;
    c.bottom_level.maxClusterCountPerAccelerationStructure = 16;
    BottomLevelInfo info{};
    info.clusterReferencesCount = uint32_t(references.size());
    info.clusterReferencesStride = 8;
    info.clusterReferences = kReferences;
    c.infos = bytes_of(&info, 1);
    c.inputs.push_back({kReferences, bytes_of(references)});
    return c;
}

ClusterCommand move_clusters(uint32_t count) {
    ClusterCommand c;
    c.info = command_info(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV,
                          Destinations::kImplicit, count,
                          sizeof(VkClusterAccelerationStructureMoveObjectsInfoNV));
    c.info.dstImplicitData = kDst2;
    c.move.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_MOVE_OBJECTS_INPUT_NV;
    c.move.type = VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_NV;
    c.move.noMoveOverlap = VK_TRUE;
    c.move.maxMovedBytes = 0x10000;
    std::vector<uint64_t> sources;
    for (uint32_t i = 0; i < count; ++i) sources.push_back(kDst + i * kExplicitStride);
    c.infos = bytes_of(sources);
    return c;
}

}  // namespace clastrace::test::catalogue
