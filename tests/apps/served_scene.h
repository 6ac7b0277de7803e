// SPDX-License-Identifier: Apache-2.0
// The scene of cluster_capture_app's `serve` mode, shared with the test that recomputes it:
// three triangle clusters built with implicit destinations, then one bottom-level structure
// whose cluster references are the dstAddressesArray the first build wrote (read on the
// device side: the application never copies them through the host).
#pragma once

#include <clastrace/vk_cluster_abi.h>

#include <cstdint>
#include <vector>

namespace served_scene {

constexpr uint32_t kClusterCount = 3;
constexpr uint32_t kMaxClusters = 4;  // maxAccelerationStructureCount: one more than used
constexpr uint64_t kInfoStride = sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV);

struct Addresses {
    uint64_t vertices = 0, indices = 0, infos = 0, counts = 0, dstAddresses = 0, dstSizes = 0,
             implicitData = 0, scratch = 0, blasInfos = 0, blasDstAddresses = 0, blasDstSizes = 0,
             blasImplicit = 0, blasScratch = 0;
};

// Cluster c is a grid of (c + 1) x (c + 2) quads on the plane z = c, two triangles a quad.
inline uint32_t quadsX(uint32_t c) { return c + 1; }
inline uint32_t quadsY(uint32_t c) { return c + 2; }

struct Inputs {
    std::vector<float> vertices;    // packed xyz, all clusters one after the other
    std::vector<uint32_t> indices;  // packed 32-bit triplets
    std::vector<VkClusterAccelerationStructureBuildTriangleClusterInfoNV> infos;
    uint32_t counts[2] = {kClusterCount, 1};  // srcInfosCount of the two builds
    VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV blasInfo{};
};

inline Inputs makeInputs(const Addresses& a) {
    Inputs in;
    for (uint32_t c = 0; c < kClusterCount; ++c) {
        const uint32_t nx = quadsX(c), ny = quadsY(c),
                       firstVertex = uint32_t(in.vertices.size() / 3);
        const uint32_t firstIndex = uint32_t(in.indices.size());
        for (uint32_t y = 0; y <= ny; ++y)
            for (uint32_t x = 0; x <= nx; ++x) {
                in.vertices.push_back(float(x) * 0.5f + float(c) * 10.0f);
                in.vertices.push_back(float(y) * 0.25f);
                in.vertices.push_back(float(c));
            }
        for (uint32_t y = 0; y < ny; ++y)
            for (uint32_t x = 0; x < nx; ++x) {
                const uint32_t v = y * (nx + 1) + x;
                for (uint32_t i : {v, v + 1, v + nx + 2, v, v + nx + 2, v + nx + 1})
                    in.indices.push_back(i);
            }
        VkClusterAccelerationStructureBuildTriangleClusterInfoNV info{};
        info.clusterID = 500 + c;
        info.triangleCount = 2 * nx * ny;
        info.vertexCount = (nx + 1) * (ny + 1);
        info.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV;
        info.baseGeometryIndexAndGeometryFlags.geometryIndex = c;
        info.indexBuffer = a.indices + uint64_t(firstIndex) * 4;
        info.vertexBuffer = a.vertices + uint64_t(firstVertex) * 12;
        in.infos.push_back(info);
    }
    in.blasInfo.clusterReferencesCount = kClusterCount;
    in.blasInfo.clusterReferencesStride = 8;
    in.blasInfo.clusterReferences = a.dstAddresses;  // what the cluster build writes there
    return in;
}

// opInput points into the struct itself: keep it where it was filled.
struct Commands {
    VkClusterAccelerationStructureTriangleClusterInputNV triangles{};
    VkClusterAccelerationStructureClustersBottomLevelInputNV bottomLevel{};
    VkClusterAccelerationStructureCommandsInfoNV clusters{}, blas{};
};

inline void makeCommands(const Addresses& a, Commands& c) {
    c.triangles.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
    c.triangles.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    c.triangles.maxGeometryIndexValue = kClusterCount;
    c.triangles.maxClusterUniqueGeometryCount = 1;
    c.triangles.maxClusterTriangleCount = 2 * quadsX(kClusterCount - 1) * quadsY(kClusterCount - 1);
    c.triangles.maxClusterVertexCount =
        (quadsX(kClusterCount - 1) + 1) * (quadsY(kClusterCount - 1) + 1);
    c.triangles.maxTotalTriangleCount = kMaxClusters * c.triangles.maxClusterTriangleCount;
    c.triangles.maxTotalVertexCount = kMaxClusters * c.triangles.maxClusterVertexCount;
    c.clusters.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    c.clusters.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    c.clusters.input.maxAccelerationStructureCount = kMaxClusters;
    c.clusters.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
    c.clusters.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    c.clusters.input.opInput.pTriangleClusters = &c.triangles;
    c.clusters.dstImplicitData = a.implicitData;
    c.clusters.scratchData = a.scratch;
    c.clusters.dstAddressesArray = {a.dstAddresses, 8, 8 * kMaxClusters};
    c.clusters.dstSizesArray = {a.dstSizes, 4, 4 * kMaxClusters};
    c.clusters.srcInfosArray = {a.infos, kInfoStride, kInfoStride * kMaxClusters};
    c.clusters.srcInfosCount = a.counts;

    c.bottomLevel.sType =
        VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_CLUSTERS_BOTTOM_LEVEL_INPUT_NV;
    c.bottomLevel.maxTotalClusterCount = kMaxClusters;
    c.bottomLevel.maxClusterCountPerAccelerationStructure = kMaxClusters;
    c.blas.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    c.blas.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    c.blas.input.maxAccelerationStructureCount = 1;
    c.blas.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV;
    c.blas.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    c.blas.input.opInput.pClustersBottomLevel = &c.bottomLevel;
    c.blas.dstImplicitData = a.blasImplicit;
    c.blas.scratchData = a.blasScratch;
    c.blas.dstAddressesArray = {a.blasDstAddresses, 8, 8};
    c.blas.dstSizesArray = {a.blasDstSizes, 4, 4};
    c.blas.srcInfosArray = {a.blasInfos, 0,
                            sizeof(VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV)};
    c.blas.srcInfosCount = a.counts + 4;
}

}  // namespace served_scene
