// SPDX-License-Identifier: Apache-2.0
// The ray check's model of NV scenes (capture/src/nv_scene_model.cpp), on hand-made build
// inputs: the hit-shader tables, the refusals, and the rays it aims.
#include "clastrace/capture/nv_scene_model.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>

namespace clastrace::capture {
namespace {

template <typename T>
CapturedRange range(MemoryRole role, uint32_t entry, const std::vector<T>& values) {
    CapturedRange r{role, entry, 0, {}};
    std::memcpy(r.bytes.fill(values.size() * sizeof(T)), values.data(), values.size() * sizeof(T));
    return r;
}

VkGeometryNV triangles(uint32_t vertexCount, uint64_t stride) {
    VkGeometryNV g{};
    g.geometryType = VK_GEOMETRY_TYPE_TRIANGLES_NV;
    g.geometry.triangles.vertexCount = vertexCount;
    g.geometry.triangles.vertexStride = stride;
    g.geometry.triangles.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    return g;
}
VkGeometryNV boxes(uint32_t count, uint32_t stride) {
    VkGeometryNV g{};
    g.geometryType = VK_GEOMETRY_TYPE_AABBS_NV;
    g.geometry.aabbs.numAABBs = count;
    g.geometry.aabbs.stride = stride;
    return g;
}

struct Instance {
    float transform[12];
    uint32_t customAndMask;
    uint32_t offsetAndFlags;
    uint64_t reference;
};
static_assert(sizeof(Instance) == 64);
Instance instance(float tx, uint32_t custom, uint32_t mask, uint32_t sbt, uint64_t reference) {
    return {{1, 0, 0, tx, 0, 1, 0, 0, 0, 0, 1, 0}, custom | (mask << 24), sbt, reference};
}

// A triangle bottom level (handle 0xB1) spanning x,z in [0,2] with a transform lifting it by 5,
// and a box bottom level (0xB2) with two boxes (stride 32).
class NvSceneModelTest : public ::testing::Test {
protected:
    void SetUp() override {
        model.set_handle(1, 0xB1);
        model.set_handle(2, 0xB2);
        model.set_handle(3, 0x70);
        BuildAccelerationStructureNVCommand tri;
        tri.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
        tri.dst = 1;
        tri.geometries = {triangles(3, 16)};
        std::vector<float> vertices = {0, 0, 0, 9, 2, 0, 0, 9, 0, 0, 2, 9};
        std::vector<float> lift = {1, 0, 0, 0, 0, 1, 0, 5, 0, 0, 1, 0};
        model.observe_build(tri, {range(MemoryRole::kVertexBuffer, 0, vertices),
                                  range(MemoryRole::kTransformData, 0, lift)});
        BuildAccelerationStructureNVCommand box;
        box.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
        box.dst = 2;
        box.geometries = {boxes(2, 32)};
        std::vector<float> data = {0, 0, 0, 1, 1, 1, 7, 7, 3, 3, 3, 4, 4, 4, 7, 7};
        model.observe_build(box, {range(MemoryRole::kAabbs, 0, data)});
    }
    void topLevel(const std::vector<Instance>& instances) {
        BuildAccelerationStructureNVCommand top;
        top.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV;
        top.dst = 3;
        top.instance_count = uint32_t(instances.size());
        model.observe_build(top, {range(MemoryRole::kInstances, 0, instances)});
    }
    NvSceneModel model;
    NvTraceScene scene;
    std::vector<NvTracedRay> rays;
    uint64_t handle = 0;
    std::string why;
};

TEST_F(NvSceneModelTest, TablesNameEachInstancesGeometriesAndBoxes) {
    topLevel({instance(0, 10, 0xFF, 0, 0xB1), instance(10, 11, 0xFF, 1, 0xB2),
              instance(-10, 12, 0x01, 0, 0xB1)});
    ASSERT_TRUE(model.prepare(3, 256, scene, rays, handle, why)) << why;
    EXPECT_EQ(handle, 0x70u);
    ASSERT_EQ(scene.instances.size(), 3u);
    EXPECT_EQ(scene.instances[0].first_geometry_slot,
              scene.instances[2].first_geometry_slot);  // shared bottom level
    EXPECT_EQ(scene.instances[1].sbt_record_offset, 1u);
    ASSERT_EQ(scene.geometry_is_aabb.size(), 2u);
    const uint32_t boxSlot = scene.instances[1].first_geometry_slot;
    EXPECT_TRUE(scene.geometry_is_aabb[boxSlot]);
    EXPECT_FALSE(scene.geometry_is_aabb[scene.instances[0].first_geometry_slot]);
    // The boxes, with the stride's padding dropped.
    const std::vector<float> expected = {0, 0, 0, 1, 1, 1, 3, 3, 3, 4, 4, 4};
    EXPECT_EQ(scene.boxes, expected);
    EXPECT_EQ(scene.geometry_first_box[boxSlot], 0u);
    EXPECT_EQ(scene.record_is_procedural, (std::vector<uint8_t>{0, 1}));
}

float slab(const NvTracedRay& r, const float lo[3], const float hi[3]) {
    float entry = -INFINITY, exit = INFINITY;
    for (int k = 0; k < 3; ++k) {
        // A millimetre of slack: the flat triangle's box has no thickness in y.
        const float t0 = (lo[k] - 1e-3f - r.origin[k]) / r.direction[k],
                    t1 = (hi[k] + 1e-3f - r.origin[k]) / r.direction[k];
        entry = std::max(entry, std::min(t0, t1));
        exit = std::min(exit, std::max(t0, t1));
    }
    return entry <= exit && exit >= 0 ? entry : NAN;
}

TEST_F(NvSceneModelTest, EvenRaysPassThroughAnInstancesWorldBoundsAndAreDeterministic) {
    topLevel({instance(0, 10, 0xFF, 0, 0xB1), instance(10, 11, 0xFF, 1, 0xB2),
              instance(-10, 12, 0, 0, 0xB1)});
    ASSERT_TRUE(model.prepare(3, 400, scene, rays, handle, why)) << why;
    ASSERT_EQ(rays.size(), 400u);
    // Masked-out instance 2 is never aimed at: targets alternate between instances 0 and 1.
    const float bounds[2][2][3] = {{{0, 5, 0}, {2, 5, 2}}, {{10, 0, 0}, {14, 4, 4}}};
    for (size_t i = 0; i < rays.size(); i += 2) {
        const auto& b = bounds[(i / 2) % 2];
        const float t = slab(rays[i], b[0], b[1]);
        EXPECT_FALSE(std::isnan(t)) << "ray " << i;
        const float len =
            std::hypot(rays[i].direction[0], rays[i].direction[1], rays[i].direction[2]);
        EXPECT_NEAR(len, 1.0f, 1e-5f);
        EXPECT_LT(rays[i].t_min, rays[i].t_max);
    }
    std::vector<NvTracedRay> again;
    NvTraceScene sceneAgain;
    ASSERT_TRUE(model.prepare(3, 400, sceneAgain, again, handle, why));
    EXPECT_EQ(std::memcmp(again.data(), rays.data(), rays.size() * sizeof(NvTracedRay)), 0);
}

TEST_F(NvSceneModelTest, RefusesUnknownBottomLevelsSharedRecordsAndHugeOffsets) {
    topLevel({instance(0, 10, 0xFF, 0, 0xDEAD)});
    EXPECT_FALSE(model.prepare(3, 16, scene, rays, handle, why));
    EXPECT_NE(why.find("dead"), std::string::npos) << why;
    topLevel({instance(0, 10, 0xFF, 0, 0xB1), instance(10, 11, 0xFF, 0, 0xB2)});
    EXPECT_FALSE(model.prepare(3, 16, scene, rays, handle, why));
    EXPECT_NE(why.find("both triangle and AABB"), std::string::npos) << why;
    topLevel({instance(0, 10, 0xFF, 0xFFFFFF, 0xB1)});
    EXPECT_FALSE(model.prepare(3, 16, scene, rays, handle, why));
    EXPECT_NE(why.find("hit records"), std::string::npos) << why;
    EXPECT_FALSE(model.prepare(99, 16, scene, rays, handle, why));  // never built
}

TEST_F(NvSceneModelTest, NonFiniteVerticesDoNotPoisonTheBounds) {
    BuildAccelerationStructureNVCommand tri;
    tri.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
    tri.dst = 1;
    tri.geometries = {triangles(3, 12)};
    const float inf = INFINITY;
    std::vector<float> vertices = {0, 0, 0, NAN, 1, 1, 1, inf, 1};
    model.observe_build(tri, {range(MemoryRole::kVertexBuffer, 0, vertices)});
    topLevel({instance(0, 10, 0xFF, 0, 0xB1)});
    ASSERT_TRUE(model.prepare(3, 8, scene, rays, handle, why)) << why;
    for (const auto& r : rays)
        for (int k = 0; k < 3; ++k) {
            EXPECT_TRUE(std::isfinite(r.origin[k]));
            EXPECT_TRUE(std::isfinite(r.direction[k]));
        }
}

TEST_F(NvSceneModelTest, ForgottenStructuresAreNoLongerKnown) {
    topLevel({instance(0, 10, 0xFF, 0, 0xB1)});
    model.forget(1);
    EXPECT_FALSE(model.prepare(3, 8, scene, rays, handle, why));
}

}  // namespace
}  // namespace clastrace::capture
