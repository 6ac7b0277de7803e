// SPDX-License-Identifier: Apache-2.0
// The ray check's inputs from outside: CLASTRACE_RAY_CHECK values, and build inputs shorter than
// their counts say (the capture keeps what it could read; the model must not read past it).
#include "clastrace/capture/layer_config.h"
#include "clastrace/capture/nv_scene_model.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <map>

namespace clastrace::capture {
namespace {

LayerConfig parse(const char* value) {
    return parse_layer_config([&](const char* name) -> const char* {
        return std::strcmp(name, "CLASTRACE_RAY_CHECK") == 0 ? value : nullptr;
    });
}

TEST(RayCheckConfig, AcceptsCountsUpToTheLimitAndNamesRejectedValues) {
    EXPECT_EQ(parse(nullptr).ray_check_rays, 0u);
    EXPECT_EQ(parse("4096").ray_check_rays, 4096u);
    EXPECT_EQ(parse("0").ray_check_rays, 0u);
    EXPECT_EQ(parse("1048576").ray_check_rays, 1048576u);
    for (const char* bad : {"1048577", "-1", "many", "", "99999999999999999999"}) {
        const LayerConfig c = parse(bad);
        EXPECT_EQ(c.ray_check_rays, 0u) << bad;
        ASSERT_EQ(c.errors.size(), 1u) << bad;
        EXPECT_NE(c.errors[0].find("CLASTRACE_RAY_CHECK"), std::string::npos) << c.errors[0];
    }
}

CapturedRange bytes(MemoryRole role, uint32_t entry, size_t size, float fill) {
    CapturedRange r{role, entry, 0, {}};
    std::vector<float> values((size + 3) / 4, fill);
    std::memcpy(r.bytes.fill(size), values.data(), size);
    return r;
}

TEST(RayCheckInputs, TruncatedRangesAreReadOnlyAsFarAsTheyGo) {
    NvSceneModel model;
    model.set_handle(1, 0xB1);
    model.set_handle(2, 0xB2);
    BuildAccelerationStructureNVCommand tri;
    tri.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
    tri.dst = 1;
    VkGeometryNV g{};
    g.geometryType = VK_GEOMETRY_TYPE_TRIANGLES_NV;
    g.geometry.triangles.vertexCount = 1000000;  // claims far more than captured
    g.geometry.triangles.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    tri.geometries = {g};
    model.observe_build(tri, {bytes(MemoryRole::kVertexBuffer, 0, 30, 1.0f),  // 2.5 vertices
                              bytes(MemoryRole::kTransformData, 0, 20,
                                    2.0f)});  // short transform: ignored
    BuildAccelerationStructureNVCommand box;
    box.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
    box.dst = 2;
    VkGeometryNV a{};
    a.geometryType = VK_GEOMETRY_TYPE_AABBS_NV;
    a.geometry.aabbs.numAABBs = 3;
    a.geometry.aabbs.stride = 24;
    box.geometries = {a};
    model.observe_build(box, {bytes(MemoryRole::kAabbs, 0, 30, 1.0f)});  // one box and a quarter
    BuildAccelerationStructureNVCommand top;
    top.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV;
    top.dst = 3;
    top.instance_count = 2;
    CapturedRange instances{MemoryRole::kInstances, 0, 0, {}};
    std::vector<uint8_t> records(64 + 40);  // one whole record and a torn one
    const float identity[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    std::memcpy(records.data(), identity, 48);
    const uint32_t customAndMask = 5u | (0xFFu << 24), sbt = 0;
    const uint64_t reference = 0xB1;
    std::memcpy(records.data() + 48, &customAndMask, 4);
    std::memcpy(records.data() + 52, &sbt, 4);
    std::memcpy(records.data() + 56, &reference, 8);
    instances.bytes = records;
    model.observe_build(top, {instances});

    NvTraceScene scene;
    std::vector<NvTracedRay> rays;
    uint64_t handle = 0;
    std::string why;
    ASSERT_TRUE(model.prepare(3, 32, scene, rays, handle, why)) << why;
    EXPECT_EQ(scene.instances.size(), 1u);  // the torn record is not an instance
    EXPECT_EQ(rays.size(), 32u);
    for (const auto& r : rays)
        for (int k = 0; k < 3; ++k)
            EXPECT_TRUE(std::isfinite(r.origin[k]) && std::isfinite(r.direction[k]));

    // The box bottom level kept its three boxes, zero past the captured bytes.
    top.dst = 4;
    const uint64_t boxReference = 0xB2;
    std::memcpy(records.data() + 56, &boxReference, 8);
    instances.bytes = records;
    model.observe_build(top, {instances});
    ASSERT_TRUE(model.prepare(4, 4, scene, rays, handle, why)) << why;
    ASSERT_EQ(scene.boxes.size(), 18u);
    EXPECT_EQ(scene.boxes[0], 1.0f);
    EXPECT_EQ(scene.boxes[6], 1.0f);  // bytes 24..27: the second box's first float
    EXPECT_EQ(scene.boxes[7], 0.0f);  // bytes 28..31 were not all captured: zero
    EXPECT_EQ(scene.boxes[17], 0.0f);
}

}  // namespace
}  // namespace clastrace::capture
