// SPDX-License-Identifier: Apache-2.0
// KHR update mode: in place (src == dst) and into another object, refit to moved vertices,
// the rules an update breaks (no ALLOW_UPDATE, no src, other flags, primitives made
// inactive), and update of a top level whose instances moved.
#include "khr_scene.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>

namespace clastrace::khrtest {
namespace {

ts::TriangleMesh quad(float half, float z) {
    ts::TriangleMesh m;
    m.positions = {{-half, -half, z}, {half, -half, z}, {half, half, z}, {-half, half, z}};
    m.triangles = {{0, 1, 2}, {0, 2, 3}};
    return m;
}

BlasSpec one_mesh(ts::TriangleMesh m) {
    BlasSpec s;
    s.geometries.push_back({std::move(m), {}, VK_GEOMETRY_OPAQUE_BIT_KHR});
    return s;
}

// Moves every vertex of the info's first geometry by dz (the mesh's positions after junk).
void move_vertices(NvWorld& w, const eng::KhrBuildInfo& info, float dz, float nan_x_of = -1) {
    const auto& t = info.geometries[0].triangles;
    for (uint32_t v = 0; v <= t.max_vertex; ++v) {
        float p[3];
        const uint64_t at = t.vertex_data + uint64_t(v) * 12;
        std::memcpy(p, w.memory.read_bytes(at, 12, {}).data(), 12);
        p[2] += dz;
        if (float(v) == nan_x_of) p[0] = std::nanf("");
        std::memcpy(w.memory.write_bytes(at, 12, {}).data(), p, 12);
    }
}

float hit_t(const NvWorld& w, uint64_t blas, float x = 0.1f, float y = 0.2f) {
    auto scene = eng::NvScene::open_bottom(w.memory, blas, nullptr);
    if (!scene) return -1;
    const eng::NvHit h = scene->closest(eng::Ray{{x, y, -10}, 0, {0, 0, 1}, 100}, 0, 0xFF);
    return h.hit ? h.t : -1;
}

eng::KhrBuildInfo as_update(eng::KhrBuildInfo info, const eng::KhrObject& src) {
    info.mode = VK_BUILD_ACCELERATION_STRUCTURE_MODE_UPDATE_KHR;
    info.src = src;
    return info;
}

TEST(KhrUpdate, InPlaceAndIntoAnotherObjectRefitToMovedVertices) {
    NvWorld w;
    eng::KhrBuildInfo info = blas_info(w, one_mesh(quad(1, 0)), {},
                                       VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_UPDATE_BIT_KHR);
    ASSERT_TRUE(build(w, info).ops[0].executed);
    EXPECT_FLOAT_EQ(hit_t(w, info.dst.address), 10.0f);
    move_vertices(w, info, 2.0f);
    eng::KhrBuildInfo in_place = as_update(info, info.dst);
    const auto r = build(w, in_place);
    ASSERT_TRUE(r.ops[0].executed);
    EXPECT_TRUE(r.findings.empty()) << r.findings[0].rule << ": " << r.findings[0].message;
    EXPECT_FLOAT_EQ(hit_t(w, info.dst.address), 12.0f);
    const eng::MemoryAccess* src = nullptr;
    for (const auto& a : r.accesses)
        if (a.field == "pInfos[0].srcAccelerationStructure") src = &a;
    ASSERT_NE(src, nullptr);
    EXPECT_FALSE(src->is_write);
    move_vertices(w, info, 3.0f);
    eng::KhrBuildInfo other = as_update(info, info.dst);
    other.dst = {};  // build() gives it a fresh object
    ASSERT_TRUE(build(w, other).ops[0].executed);
    EXPECT_FLOAT_EQ(hit_t(w, other.dst.address), 15.0f);
    EXPECT_FLOAT_EQ(hit_t(w, info.dst.address), 12.0f);  // src untouched
}

TEST(KhrUpdate, WithoutAllowUpdateOrSrcNothingIsWritten) {
    NvWorld w;
    eng::KhrBuildInfo info = blas_info(w, one_mesh(quad(1, 0)), {});
    ASSERT_TRUE(build(w, info).ops[0].executed);
    eng::KhrBuildInfo update = as_update(info, info.dst);
    auto r = build(w, update);
    EXPECT_TRUE(has(r, eng::kVuidKhrUpdateNotAllowed));
    EXPECT_FALSE(r.ops[0].executed);
    update = as_update(info, eng::KhrObject{});
    r = build(w, update);
    EXPECT_TRUE(has(r, eng::kVuidKhrUpdateNoSrc));
    EXPECT_FALSE(r.ops[0].executed);
}

TEST(KhrUpdate, OtherFlagsAndPrimitivesMadeInactiveAreReported) {
    NvWorld w;
    eng::KhrBuildInfo info = blas_info(w, one_mesh(quad(1, 0)), {},
                                       VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_UPDATE_BIT_KHR);
    ASSERT_TRUE(build(w, info).ops[0].executed);
    move_vertices(w, info, 0.0f, 1.0f);  // vertex 1 gets NaN X: triangle 0 becomes inactive
    eng::KhrBuildInfo update = as_update(info, info.dst);
    update.flags |= VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_TRACE_BIT_KHR;
    const auto r = build(w, update);
    EXPECT_TRUE(has(r, eng::kVuidKhrUpdateFlags));
    EXPECT_TRUE(has(r, eng::kVuidKhrMadeInactive));
}

TEST(KhrUpdate, TopLevelUpdateFollowsMovedInstances) {
    NvWorld w;
    eng::KhrBuildInfo b = blas_info(w, one_mesh(quad(1, 0)), {});
    ASSERT_TRUE(build(w, b).ops[0].executed);
    std::vector<InstanceSpec> instances(2);
    instances[1].transform[3] = 5;  // x + 5
    const uint64_t data = put_instances(w, instances, {b.dst.address}, false);
    eng::KhrBuildInfo top =
        tlas_info(data, 2, false, VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_UPDATE_BIT_KHR);
    ASSERT_TRUE(build(w, top).ops[0].executed);
    auto trace = [&](float x) {
        auto scene = eng::NvScene::open(w.memory, top.dst.address, nullptr, nullptr);
        if (!scene) return -1.0f;
        const eng::NvHit h = scene->closest(eng::Ray{{x, 0.2f, -10}, 0, {0, 0, 1}, 100}, 0, 0xFF);
        return h.hit ? h.t : -1.0f;
    };
    EXPECT_FLOAT_EQ(trace(5.1f), 10.0f);
    const float z = 4;  // instance 1 moves 4 along z
    std::memcpy(w.memory.write_bytes(data + 64 + 44, 4, {}).data(), &z, 4);
    eng::KhrBuildInfo update = as_update(top, top.dst);
    const auto r = build(w, update);
    ASSERT_TRUE(r.ops[0].executed);
    EXPECT_TRUE(r.findings.empty()) << r.findings[0].message;
    EXPECT_FLOAT_EQ(trace(5.1f), 14.0f);
    EXPECT_FLOAT_EQ(trace(0.1f), 10.0f);
}

}  // namespace
}  // namespace clastrace::khrtest
