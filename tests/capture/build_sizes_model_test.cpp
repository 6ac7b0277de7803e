#include "clastrace/capture/build_sizes_model.h"
#include "clastrace/capture/cluster_limits.h"

#include <gtest/gtest.h>

using namespace clastrace::capture;

namespace {
VkAccelerationStructureBuildSizesInfoKHR sizesFor(VkClusterAccelerationStructureInputInfoNV input) {
  VkAccelerationStructureBuildSizesInfoKHR sizes{};
  EXPECT_TRUE(conservativeClusterBuildSizes(input, servedClusterProperties(), sizes));
  return sizes;
}
VkClusterAccelerationStructureInputInfoNV triangles(VkClusterAccelerationStructureTriangleClusterInputNV* t, uint32_t count) {
  VkClusterAccelerationStructureInputInfoNV input{};
  input.maxAccelerationStructureCount = count;
  input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
  input.opInput.pTriangleClusters = t;
  return input;
}
}  // namespace

// The bound must hold at least the raw input: vertices as given and 3 indices per triangle.
TEST(BuildSizesModel, TriangleClustersHoldTheirRawInputAndAreAligned) {
  VkClusterAccelerationStructureTriangleClusterInputNV t{};
  t.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
  t.maxClusterTriangleCount = 128;
  t.maxClusterVertexCount = 128;
  t.maxTotalTriangleCount = 128 * 8;
  t.maxTotalVertexCount = 128 * 8;
  auto sizes = sizesFor(triangles(&t, 8));
  EXPECT_GE(sizes.accelerationStructureSize, 8u * (128 * 12 + 128 * 3));
  EXPECT_EQ(sizes.buildScratchSize % servedClusterProperties().clusterScratchByteAlignment, 0u);
  EXPECT_EQ(sizes.updateScratchSize, 0u);
}

TEST(BuildSizesModel, TotalsTightenThePerClusterBound) {
  VkClusterAccelerationStructureTriangleClusterInputNV t{};
  t.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
  t.maxClusterTriangleCount = 256;
  t.maxClusterVertexCount = 256;
  t.maxTotalTriangleCount = 256;  // 100 clusters may share only one cluster's worth of triangles
  t.maxTotalVertexCount = 256;
  auto loose = sizesFor(triangles(&t, 100));
  t.maxTotalTriangleCount = 25600;
  t.maxTotalVertexCount = 25600;
  auto full = sizesFor(triangles(&t, 100));
  EXPECT_LT(loose.accelerationStructureSize, full.accelerationStructureSize);
  EXPECT_GE(loose.accelerationStructureSize, 256u * 12 + 256u * 3);
}

TEST(BuildSizesModel, RejectsMissingOpInputAndUnknownOps) {
  VkClusterAccelerationStructureInputInfoNV input{};
  input.maxAccelerationStructureCount = 1;
  input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
  VkAccelerationStructureBuildSizesInfoKHR sizes{};
  sizes.accelerationStructureSize = 5;
  EXPECT_FALSE(conservativeClusterBuildSizes(input, servedClusterProperties(), sizes));
  EXPECT_EQ(sizes.accelerationStructureSize, 0u);
  input.opType = (VkClusterAccelerationStructureOpTypeNV)42;
  EXPECT_FALSE(conservativeClusterBuildSizes(input, servedClusterProperties(), sizes));
}

TEST(BuildSizesModel, MoveUsesMaxMovedBytes) {
  VkClusterAccelerationStructureMoveObjectsInputNV move{};
  move.maxMovedBytes = 1 << 20;
  VkClusterAccelerationStructureInputInfoNV input{};
  input.maxAccelerationStructureCount = 4;
  input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV;
  input.opInput.pMoveObjects = &move;
  EXPECT_EQ(sizesFor(input).accelerationStructureSize, 1u << 20);
}
