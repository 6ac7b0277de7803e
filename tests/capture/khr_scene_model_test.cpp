// SPDX-License-Identifier: Apache-2.0
// The ray check's scene model on hand-made KHR build inputs (capture/src/nv_scene_model.cpp,
// observe_khr_build): a two-info bottom-level build whose ranges carry the same geometry entry
// (told apart by address), direct and indirect ranges, a top level through an array of
// pointers; the tables and the rays' aim that follow, without a GPU.
#include "clastrace/capture/nv_scene_model.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>

namespace clastrace::capture {
namespace {

template <typename T>
CapturedRange range(MemoryRole role, uint32_t entry, VkDeviceAddress address,
                    const std::vector<T>& values) {
    CapturedRange r{role, entry, address, {}};
    std::memcpy(r.bytes.fill(values.size() * sizeof(T)), values.data(), values.size() * sizeof(T));
    return r;
}

struct Instance {  // VkAccelerationStructureInstanceKHR
    float transform[12];
    uint32_t customAndMask;
    uint32_t offsetAndFlags;
    uint64_t reference;
};
static_assert(sizeof(Instance) == 64);

Instance instance(float tx, uint32_t custom, uint32_t mask, uint64_t reference) {
    return {{1, 0, 0, tx, 0, 1, 0, 0, 0, 0, 1, 0}, custom | (mask << 24), 0, reference};
}

KhrBuildInfo info(VkAccelerationStructureTypeKHR type, uint64_t dst,
                  VkAccelerationStructureGeometryKHR geometry,
                  VkAccelerationStructureBuildRangeInfoKHR range) {
    KhrBuildInfo i;
    i.info.type = type;
    i.info.dstAccelerationStructure = (VkAccelerationStructureKHR)dst;
    i.geometries = {geometry};
    i.ranges = {range};
    return i;
}

constexpr VkDeviceAddress kVertices = 0x1000, kBoxes = 0x2000, kPointers = 0x3000,
                          kInstance0 = 0x4000, kInstance1 = 0x5000;

// BLAS 1: one triangle at vertices 2..4 of kVertices (non-indexed, primitiveOffset 8, so the
// range starts at kVertices + 8 + 2 * 12), x,z in [0,2] at y = 5. BLAS 2: two boxes (stride
// 32) from kBoxes + 64. One command builds both; every range's entry is geometry 0.
class KhrSceneModelTest : public ::testing::Test {
protected:
    void SetUp() override {
        model.set_handle(1, 0xB100);
        model.set_handle(2, 0xB200);
        model.set_handle(3, 0x7000);
        VkAccelerationStructureGeometryKHR tri{};
        tri.geometryType = VK_GEOMETRY_TYPE_TRIANGLES_KHR;
        tri.geometry.triangles.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
        tri.geometry.triangles.vertexStride = 12;
        tri.geometry.triangles.vertexData.deviceAddress = kVertices;
        tri.geometry.triangles.indexType = VK_INDEX_TYPE_NONE_KHR;
        VkAccelerationStructureGeometryKHR box{};
        box.geometryType = VK_GEOMETRY_TYPE_AABBS_KHR;
        box.geometry.aabbs.data.deviceAddress = kBoxes;
        box.geometry.aabbs.stride = 32;
        BuildAccelerationStructuresKHRCommand build;
        build.infos = {info(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR, 1, tri, {1, 8, 2, 0}),
                       info(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR, 2, box,
                            {2, 64, 0, 0})};
        const std::vector<float> vertices = {0, 5, 0, 2, 5, 0, 0, 5, 2};
        const std::vector<float> boxes = {0, 0, 0, 1, 1, 1, 7, 7, 3, 3, 3, 4, 4, 4, 7, 7};
        model.observe_khr_build(build, {},
                                {range(MemoryRole::kVertexBuffer, 0, kVertices + 8 + 24, vertices),
                                 range(MemoryRole::kAabbs, 0, kBoxes + 64, boxes)});
    }
    // The top level over `instances` through an array of pointers, its ranges read indirectly.
    void topLevel(const std::vector<Instance>& instances) {
        VkAccelerationStructureGeometryKHR g{};
        g.geometryType = VK_GEOMETRY_TYPE_INSTANCES_KHR;
        g.geometry.instances.arrayOfPointers = VK_TRUE;
        g.geometry.instances.data.deviceAddress = kPointers;
        BuildAccelerationStructuresKHRCommand build;
        build.indirect = true;
        build.infos = {info(VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR, 3, g, {})};
        build.infos[0].ranges.clear();
        std::vector<CapturedRange> inputs;
        std::vector<uint64_t> pointers;
        for (size_t i = 0; i < instances.size(); ++i) {
            pointers.push_back(i == 0 ? kInstance0 : kInstance1);
            inputs.push_back(range(MemoryRole::kInstances, 0, pointers.back(),
                                   std::vector<Instance>{instances[i]}));
        }
        inputs.push_back(range(MemoryRole::kInstancePointers, 0, kPointers, pointers));
        model.observe_khr_build(build, {{{uint32_t(instances.size()), 0, 0, 0}}}, inputs);
    }
    NvSceneModel model;
    NvTraceScene scene;
    std::vector<NvTracedRay> rays;
    uint64_t handle = 0;
    std::string why;
};

// Whether `r` passes through the box [lo, hi] (a millimetre of slack for flat boxes).
bool passes(const NvTracedRay& r, const float lo[3], const float hi[3]) {
    float entry = -INFINITY, exit = INFINITY;
    for (int k = 0; k < 3; ++k) {
        const float t0 = (lo[k] - 1e-3f - r.origin[k]) / r.direction[k],
                    t1 = (hi[k] + 1e-3f - r.origin[k]) / r.direction[k];
        entry = std::max(entry, std::min(t0, t1));
        exit = std::min(exit, std::max(t0, t1));
    }
    return entry <= exit && exit >= 0;
}

TEST_F(KhrSceneModelTest, EachInfoReadsItsOwnRangesAndInstancesComeThroughPointers) {
    topLevel({instance(0, 10, 0xFF, 0xB100), instance(10, 11, 0xFF, 0xB200)});
    EXPECT_TRUE(model.is_khr_top_level(3));
    EXPECT_FALSE(model.is_khr_top_level(1));
    ASSERT_TRUE(model.prepare(3, 400, scene, rays, handle, why)) << why;
    EXPECT_EQ(handle, 0x7000u);
    ASSERT_EQ(scene.instances.size(), 2u);
    ASSERT_EQ(scene.geometry_is_aabb.size(), 2u);
    EXPECT_FALSE(scene.geometry_is_aabb[scene.instances[0].first_geometry_slot]);
    EXPECT_TRUE(scene.geometry_is_aabb[scene.instances[1].first_geometry_slot]);
    // The boxes from primitiveOffset on, the stride's padding dropped.
    EXPECT_EQ(scene.boxes, (std::vector<float>{0, 0, 0, 1, 1, 1, 3, 3, 3, 4, 4, 4}));
    // Even rays alternate between the two instances' world boxes: the triangle's bounds come
    // from the vertices at firstVertex, the boxes' from the AABB range.
    const float bounds[2][2][3] = {{{0, 5, 0}, {2, 5, 2}}, {{10, 0, 0}, {14, 4, 4}}};
    ASSERT_EQ(rays.size(), 400u);
    for (size_t i = 0; i < rays.size(); i += 2)
        EXPECT_TRUE(passes(rays[i], bounds[(i / 2) % 2][0], bounds[(i / 2) % 2][1])) << i;
}

TEST_F(KhrSceneModelTest, RayQueryNeedsNoHitRecordKindPerSbtOffset) {
    // Both instances use SBT offset 0 for a triangle and a box geometry: an NV top level is
    // refused for it; a ray query has no hit groups.
    topLevel({instance(0, 10, 0xFF, 0xB100), instance(10, 11, 0xFF, 0xB200)});
    ASSERT_TRUE(model.prepare(3, 16, scene, rays, handle, why)) << why;
    EXPECT_TRUE(scene.record_is_procedural.empty());
}

TEST_F(KhrSceneModelTest, UnknownAddressAndDestroyedBottomLevelAreRefused) {
    topLevel({instance(0, 10, 0xFF, 0xDEAD)});
    EXPECT_FALSE(model.prepare(3, 16, scene, rays, handle, why));
    EXPECT_NE(why.find("0xdead"), std::string::npos) << why;
    topLevel({instance(0, 10, 0xFF, 0xB100)});
    ASSERT_TRUE(model.prepare(3, 16, scene, rays, handle, why)) << why;
    model.forget(1);
    EXPECT_FALSE(model.prepare(3, 16, scene, rays, handle, why));
}

// A traceable cluster BLAS (capture/README.md "Traceable cluster BLASes") is known by its
// address: a top level naming it is prepared (rays aimed at its clusters' triangles), and the
// driver's geometry index (the cluster's reference index) becomes the triangle's own geometry
// index; hits on KHR BLASes keep the driver's.
TEST_F(KhrSceneModelTest, TraceableClusterBlasIsKnownByItsAddress) {
    constexpr uint64_t kClusterBlas = 0xC1000;
    topLevel({instance(0, 10, 0xFF, kClusterBlas), instance(10, 11, 0xFF, 0xB100)});
    EXPECT_FALSE(model.prepare(3, 16, scene, rays, handle, why));  // not observed yet
    const float nan = std::numeric_limits<float>::quiet_NaN();
    model.observe_cluster_blas(kClusterBlas,
                               {{0, 0, 0, 1, 0, 0, 0, 1, 0, nan, nan, nan, nan, nan, nan, nan, nan,
                                 nan},
                                {0, 0, 2, 1, 0, 2, 0, 1, 2}},
                               {{7, 0xFFFFFFFFu}, {9}});
    ASSERT_TRUE(model.prepare(3, 400, scene, rays, handle, why)) << why;
    ASSERT_EQ(scene.instances.size(), 2u);
    const float lo[3] = {0, 0, 0}, hi[3] = {1, 1, 2};  // both clusters, the NaN triangle left out
    // Rays 0, 4, 8... aim at instance 0 (2, 6, 10... at instance 1, the KHR BLAS).
    for (size_t i = 0; i < rays.size(); i += 4) EXPECT_TRUE(passes(rays[i], lo, hi)) << i;

    std::vector<NvRayHit> hits(4, NvRayHit{});
    hits[0] = {1, 1.0f, 10, 0, 0, 0, 0xFE, 0, 0, {}};  // cluster reference 0, triangle 0
    hits[1] = {1, 1.0f, 10, 0, 0, 1, 0xFE, 0, 0, {}};  // cluster reference 1, triangle 0
    hits[2] = {1, 1.0f, 10, 0, 5, 1, 0xFE, 0, 0, {}};  // a triangle the model does not know
    hits[3] = {1, 1.0f, 11, 1, 0, 0, 0xFE, 0, 0, {}};  // the KHR BLAS: the driver's own index
    model.to_cluster_geometry_indices(3, hits);
    EXPECT_EQ(hits[0].geometry_index, 7u);
    EXPECT_EQ(hits[1].geometry_index, 9u);
    EXPECT_EQ(hits[2].geometry_index, 0xFFFFFFFFu);
    EXPECT_EQ(hits[3].geometry_index, 0u);
}

// Vertices in any format the engine decodes bound their geometry (here half floats with a
// fourth component): rays are aimed at the triangle as at a 32-bit float one.
TEST_F(KhrSceneModelTest, HalfFloatVerticesBoundTheirGeometry) {
    model.set_handle(4, 0xB400);
    VkAccelerationStructureGeometryKHR tri{};
    tri.geometryType = VK_GEOMETRY_TYPE_TRIANGLES_KHR;
    tri.geometry.triangles.vertexFormat = VK_FORMAT_R16G16B16A16_SFLOAT;
    tri.geometry.triangles.vertexData.deviceAddress = kVertices;
    tri.geometry.triangles.indexType = VK_INDEX_TYPE_NONE_KHR;
    BuildAccelerationStructuresKHRCommand build;
    build.infos = {info(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR, 4, tri, {1, 0, 0, 0})};
    // (0,5,0), (2,5,0), (0,5,2), w = 1: 0 = 0x0000, 1 = 0x3C00, 2 = 0x4000, 5 = 0x4500.
    const std::vector<uint16_t> halves = {0, 0x4500, 0, 0x3C00, 0x4000, 0x4500,
                                          0, 0x3C00, 0, 0x4500, 0x4000, 0x3C00};
    model.observe_khr_build(build, {}, {range(MemoryRole::kVertexBuffer, 0, kVertices, halves)});
    topLevel({instance(0, 10, 0xFF, 0xB400)});
    ASSERT_TRUE(model.prepare(3, 64, scene, rays, handle, why)) << why;
    const float lo[3] = {0, 5, 0}, hi[3] = {2, 5, 2};
    ASSERT_EQ(rays.size(), 64u);
    for (size_t i = 0; i < rays.size(); i += 2) EXPECT_TRUE(passes(rays[i], lo, hi)) << i;
}

}  // namespace
}  // namespace clastrace::capture
