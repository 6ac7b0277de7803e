// SPDX-License-Identifier: Apache-2.0
// Inputs a replay cannot trust: rays with NaN/Inf/zero parts, build inputs whose buffers are
// too small or missing, and CLAS bytes corrupted in device memory. Each is a finding or a
// miss, never a crash or an out-of-bounds read (run under ASan).
#include "clastrace/engine/cluster_build.h"
#include "clastrace/engine/cluster_format.h"
#include "clastrace/engine/traversal.h"
#include "clastrace/testsupport/cluster_scene.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <iostream>
#include <limits>
#include <random>

namespace ts = clastrace::testsupport;
namespace eng = clastrace::engine;

namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

std::vector<std::byte> build_icosphere_cluster(unsigned truncate_bits = 0) {
    const ts::TriangleMesh m = ts::make_icosphere(2, 1.0f);  // 320 triangles, 162 vertices
    const auto clusters = ts::build_clusters(m, 128, 128);
    const ts::ClusterScene scene = ts::build_cluster_scene(m, clusters, {1, 0, 0, truncate_bits});
    EXPECT_EQ(scene.failed_builds, 0u);
    return scene.objects.at(0);
}

eng::Hit trace(std::span<const std::byte> clas, std::array<float, 3> o, std::array<float, 3> d,
               float tmin = 0, float tmax = kInf) {
    eng::Ray r{{o[0], o[1], o[2]}, tmin, {d[0], d[1], d[2]}, tmax};
    return eng::trace_closest(clas, r, 0);
}

struct Inputs {
    eng::MemoryImage memory;
    VkClusterAccelerationStructureTriangleClusterInputNV input{};
    VkClusterAccelerationStructureBuildTriangleClusterInfoNV info{};
};

// 8 triangles / 9 vertices, with the vertex region sized `vertex_region_bytes`.
Inputs small_cluster(uint64_t vertex_region_bytes) {
    Inputs in;
    const VkBufferUsageFlags usage =
        VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR |
        VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT;
    auto& vr = in.memory.add_region(0x4000, vertex_region_bytes, usage, "vertices");
    auto& ir = in.memory.add_region(0x8000, 24, usage, "indices");
    std::vector<float> pos;
    for (int y = 0; y < 3; ++y)
        for (int x = 0; x < 3; ++x) pos.insert(pos.end(), {float(x), float(y), 1.0f});
    std::memcpy(vr.bytes.data(), pos.data(), std::min<size_t>(vr.bytes.size(), pos.size() * 4));
    const uint8_t idx[24] = {0, 1, 4, 0, 4, 3, 1, 2, 5, 1, 5, 4,
                             3, 4, 7, 3, 7, 6, 4, 5, 8, 4, 8, 7};
    std::memcpy(ir.bytes.data(), idx, 24);
    in.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
    in.input.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    in.input.maxClusterUniqueGeometryCount = 1;
    in.input.maxClusterTriangleCount = 8;
    in.input.maxClusterVertexCount = 9;
    in.input.maxTotalTriangleCount = 8;
    in.input.maxTotalVertexCount = 9;
    in.info.triangleCount = 8;
    in.info.vertexCount = 9;
    in.info.indexType = 1;
    in.info.indexBuffer = 0x8000;
    in.info.vertexBuffer = 0x4000;
    return in;
}

std::string text(const std::vector<eng::Finding>& fs) {
    std::string s;
    for (const auto& f : fs) s += f.rule + ": " + f.message + "\n";
    return s;
}

}  // namespace

TEST(HostileInput, DegenerateRaysMissWithoutCrashing) {
    const auto clas = build_icosphere_cluster();
    ASSERT_TRUE(trace(clas, {0, 0, -5}, {0, 0, 1}).hit);  // the sphere is there
    EXPECT_FALSE(trace(clas, {kNaN, 0, -5}, {0, 0, 1}).hit);
    EXPECT_FALSE(trace(clas, {0, 0, -5}, {0, kNaN, 1}).hit);
    EXPECT_FALSE(trace(clas, {0, 0, -5}, {0, 0, 0}).hit);            // zero direction
    EXPECT_FALSE(trace(clas, {0, 0, -5}, {0, 0, 1}, 10, 1).hit);     // tmin > tmax
    EXPECT_FALSE(trace(clas, {0, 0, -5}, {0, 0, 1}, 0, kNaN).hit);   // NaN tmax
    EXPECT_FALSE(trace(clas, {0, 0, -5}, {0, 0, 1}, kNaN, 10).hit);  // NaN tmin
    EXPECT_FALSE(trace(clas, {-kInf, 0, 0}, {1, 0, 0}).hit);         // infinite origin
    // Infinite and huge direction components: no crash, and no NaN t.
    for (std::array<float, 3> d :
         {std::array<float, 3>{0, 0, kInf}, std::array<float, 3>{3e38f, 0, 3e38f}}) {
        const eng::Hit h = trace(clas, {0, 0, -5}, d);
        if (h.hit) {
            EXPECT_FALSE(std::isnan(h.t));
            EXPECT_GE(h.t, 0.0f);
        }
    }
    // Denormal directions: the sphere is 4 / 1e-40 = 4e40 away, beyond FLT_MAX. With
    // tmax = FLT_MAX that is a miss; with tmax = inf, a hit may only report t = inf (the
    // float rounding of 4e40).
    for (std::array<float, 3> d :
         {std::array<float, 3>{0, 0, 1e-40f}, std::array<float, 3>{1e-45f, 1e-45f, 1e-44f}}) {
        EXPECT_FALSE(trace(clas, {0, 0, -5}, d, 0, std::numeric_limits<float>::max()).hit);
        const eng::Hit h = trace(clas, {0, 0, -5}, d);
        if (h.hit) {
            EXPECT_EQ(h.t, kInf);
        }
    }
    EXPECT_FALSE(eng::trace_any(clas, eng::Ray{{kNaN, 0, 0}, 0, {1, 0, 0}, kInf}, 0));
}

TEST(HostileInput, TooSmallVertexBufferIsAFindingNamingTheAddress) {
    Inputs in = small_cluster(9 * 12 - 4);  // the last vertex runs off the region
    const eng::ClusterObject obj =
        eng::build_triangle_cluster(in.memory, in.info, in.input,
                                    eng::EngineProperties::nvidia_default(), 3);
    EXPECT_FALSE(obj.ok);
    ASSERT_FALSE(obj.findings.empty());
    bool named = false;
    for (const auto& f : obj.findings)
        named = named || (f.op_index == 3 && f.message.find("vertexBuffer") != std::string::npos);
    EXPECT_TRUE(named) << text(obj.findings);
}

TEST(HostileInput, MissingOrWrappingBuffersAreFindings) {
    for (uint64_t index_address : {uint64_t(0), uint64_t(0x7FFF), ~uint64_t(0) - 3}) {
        Inputs in = small_cluster(9 * 12);
        in.info.indexBuffer = index_address;
        const eng::ClusterObject obj =
            eng::build_triangle_cluster(in.memory, in.info, in.input,
                                        eng::EngineProperties::nvidia_default(), 0);
        EXPECT_FALSE(obj.ok) << std::hex << index_address;
        EXPECT_FALSE(obj.findings.empty());
    }
    // A stride that walks the 9th vertex past the region.
    Inputs in = small_cluster(9 * 12);
    in.info.vertexBufferStride = 16;
    const eng::ClusterObject obj =
        eng::build_triangle_cluster(in.memory, in.info, in.input,
                                    eng::EngineProperties::nvidia_default(), 0);
    EXPECT_FALSE(obj.ok);
    EXPECT_FALSE(obj.findings.empty());
}

TEST(HostileInput, MisalignedStridesAreFindings) {
    Inputs in = small_cluster(9 * 14);
    in.info.vertexBufferStride = 14;  // not a multiple of the 4-byte component
    const eng::ClusterObject obj =
        eng::build_triangle_cluster(in.memory, in.info, in.input,
                                    eng::EngineProperties::nvidia_default(), 0);
    bool vuid = false;
    for (const auto& f : obj.findings)
        vuid = vuid || f.rule.find("vertexBufferStride") != std::string::npos;
    EXPECT_TRUE(vuid) << text(obj.findings);
}

// A CLAS overwritten in device memory: random byte mutations of a valid object, traced. The
// engine may reject the object or trace garbage, but must stay inside the bytes it was given.
TEST(HostileInput, CorruptedClasBytesNeverCrashTraversal) {
    const auto good = build_icosphere_cluster(8);
    const auto hc = eng::read_object_header(good);
    ASSERT_TRUE(hc.header) << hc.error;
    std::mt19937_64 rng(1234);
    const auto rays = ts::random_rays(ts::Bounds{{{-1, -1, -1}}, {{1, 1, 1}}}, 16, 5);
    size_t rejected = 0, traced = 0;
    for (int iter = 0; iter < 3000; ++iter) {
        std::vector<std::byte> bad = good;
        const int flips = 1 + int(rng() % 8);
        for (int k = 0; k < flips; ++k) {
            const size_t at = rng() % bad.size();
            // Half the time, aim at the header and node area where offsets and links live.
            const size_t pos =
                (rng() & 1) ? at % std::min<size_t>(bad.size(), 96 + 8 * hc.header->node_count + 64)
                            : at;
            bad[pos] = std::byte(rng());
        }
        if ((rng() & 7) == 0) bad.resize(rng() % bad.size());  // truncated object
        if (!eng::read_object_header(bad).header) ++rejected;
        for (const auto& r : rays) {
            eng::Ray er{{r.origin[0], r.origin[1], r.origin[2]},
                        0,
                        {r.direction[0], r.direction[1], r.direction[2]},
                        kInf};
            const eng::Hit h = eng::trace_closest(bad, er, 0);
            (void)eng::trace_any(bad, er, 0);
            if (h.hit) {
                EXPECT_FALSE(std::isnan(h.t));
            }
            ++traced;
        }
    }
    std::cout << "[corrupt] objects 3000, header rejected " << rejected << ", rays traced "
              << traced << "\n";
    EXPECT_GT(rejected, 0u);
}
