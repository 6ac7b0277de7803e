// SPDX-License-Identifier: Apache-2.0
// Vertex formats decode to the values the format defines, and truncation zeroes exactly
// the low N bits of each coordinate's 32-bit pattern, before anything else.
#include "clastrace/common/enum_bits.h"
#include "clastrace/engine/cluster_build.h"
#include "clastrace/engine/cluster_format.h"
#include "clastrace/engine/vertex_format.h"
#include "engine_test_util.h"

#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <limits>
#include <random>

namespace clastrace::engine {
namespace {

using test::Arena;

uint32_t bits_of(float f) { return std::bit_cast<uint32_t>(f); }

TEST(Truncation, EveryBitCountZeroesExactlyTheLowBits) {
    std::mt19937 rng(42);
    for (uint32_t n = 0; n <= 32; ++n) {
        for (int i = 0; i < 200; ++i) {
            const uint32_t pattern = rng();
            const uint32_t expected = n == 32 ? 0u : (pattern >> n) << n;
            EXPECT_EQ(bits_of(truncate_position(std::bit_cast<float>(pattern), n)), expected)
                << "n=" << n;
        }
    }
    EXPECT_EQ(bits_of(truncate_position(-1.0f, 32)), 0u);  // sign goes too at 32
    EXPECT_EQ(bits_of(truncate_position(1.9999999f, 23)), bits_of(1.0f));
}

// Builds a one-vertex-per-coordinate cluster through the MemoryImage and checks the stored
// positions bit for bit.
TEST(Truncation, StoredPositionsMatchTheGpuPatternForEveryBitCount) {
    std::mt19937 rng(7);
    std::vector<float> pos;
    for (int i = 0; i < 3 * 40; ++i) {
        float f;
        do f = std::bit_cast<float>(uint32_t(rng()));
        while (std::isnan(f));
        pos.push_back(f);
    }
    pos[0] = 1.0e-45f;  // denormal
    pos[1] = -3.4e38f;
    pos[2] = std::numeric_limits<float>::infinity();
    std::vector<uint32_t> idx;
    for (uint32_t t = 0; t + 2 < 40; ++t) idx.insert(idx.end(), {t, t + 1, t + 2});
    for (uint32_t n = 0; n <= 32; ++n) {
        Arena arena;
        VkClusterAccelerationStructureBuildTriangleClusterInfoNV info{};
        info.clusterID = 1;
        info.triangleCount = uint32_t(idx.size() / 3);
        info.vertexCount = 40;
        info.positionTruncateBitCount = n;
        info.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV;
        info.indexBuffer = arena.put_vec(idx);
        info.vertexBuffer = arena.put_vec(pos);
        const ClusterObject o = build_triangle_cluster(arena.memory, info, test::default_input(),
                                                       EngineProperties{}, 0);
        ASSERT_TRUE(o.ok);
        const auto h = read_object_header(o.bytes).header;
        ASSERT_TRUE(h);
        EXPECT_EQ(h->position_truncate_bits, n);
        for (uint32_t v = 0; v < 40; ++v) {
            float xyz[3];
            decode_position(o.bytes, *h, v, xyz);
            for (int k = 0; k < 3; ++k) {
                const uint32_t p = bits_of(pos[3 * v + k]);
                EXPECT_EQ(bits_of(xyz[k]), n == 32 ? 0u : (p >> n) << n) << "n=" << n << " v=" << v;
            }
        }
    }
}

TEST(Truncation, PackingSavesPositionBytes) {
    const test::Mesh m = test::grid(8);
    ClusterBuilder b;
    std::vector<std::byte> a, c;
    std::vector<Finding> f;
    ASSERT_TRUE(b.build_from_arrays(0, m.positions, m.indices, 0, 0, {}, a, f));
    ASSERT_TRUE(b.build_from_arrays(0, m.positions, m.indices, 16, 0, {}, c, f));
    // 81 vertices * 3 coordinates * 16 bits saved = 486 bytes (up to alignment).
    EXPECT_GE(a.size() - c.size(), 480u);
    EXPECT_LE(a.size() - c.size(), 490u);
}

struct FormatCase {
    VkFormat format;
    std::vector<uint8_t> bytes;  // one vertex
    float expected[3];
};

std::vector<uint8_t> le16(std::initializer_list<uint16_t> v) {
    std::vector<uint8_t> out;
    for (uint16_t x : v) out.insert(out.end(), {uint8_t(x & 0xFF), uint8_t(x >> 8)});
    return out;
}
std::vector<uint8_t> le32(std::initializer_list<float> v) {
    std::vector<uint8_t> out;
    for (float f : v) {
        const uint32_t x = bits_of(f);
        out.insert(out.end(), {uint8_t(x), uint8_t(x >> 8), uint8_t(x >> 16), uint8_t(x >> 24)});
    }
    return out;
}

TEST(VertexFormat, EveryFormatDecodes) {
    const std::vector<FormatCase> cases = {
        {VK_FORMAT_R32G32B32_SFLOAT, le32({1.5f, -2.0f, 3.25f}), {1.5f, -2.0f, 3.25f}},
        {VK_FORMAT_R32G32B32A32_SFLOAT, le32({1.5f, -2.0f, 3.25f, 9.0f}), {1.5f, -2.0f, 3.25f}},
        {VK_FORMAT_R32G32_SFLOAT, le32({1.5f, -2.0f}), {1.5f, -2.0f, 0.0f}},
        // half: 0x3C00 = 1, 0xC000 = -2, 0x0001 = 2^-24 (denormal), 0x7BFF = 65504
        {VK_FORMAT_R16G16B16A16_SFLOAT,
         le16({0x3C00, 0xC000, 0x0001, 0x3C00}),
         {1.0f, -2.0f, 5.9604645e-8f}},
        {VK_FORMAT_R16G16B16_SFLOAT, le16({0x7BFF, 0x3800, 0x8000}), {65504.0f, 0.5f, -0.0f}},
        {VK_FORMAT_R16G16_SFLOAT, le16({0x3C00, 0xC000}), {1.0f, -2.0f, 0.0f}},
        {VK_FORMAT_R16G16B16A16_SNORM, le16({32767, 0x8000, 0x8001, 0}), {1.0f, -1.0f, -1.0f}},
        {VK_FORMAT_R16G16_SNORM,
         le16({16384, 0xC000}),
         {16384.0f / 32767.0f, -16384.0f / 32767.0f, 0.0f}},
        {VK_FORMAT_R16G16B16A16_UNORM,
         le16({65535, 0, 32768, 1}),
         {1.0f, 0.0f, 32768.0f / 65535.0f}},
        {VK_FORMAT_R16G16_UNORM, le16({65535, 1}), {1.0f, 1.0f / 65535.0f, 0.0f}},
        {VK_FORMAT_R8G8B8A8_SNORM, {127, 0x80, 0xC0, 5}, {1.0f, -1.0f, -64.0f / 127.0f}},
        {VK_FORMAT_R8G8_SNORM, {64, 0x81}, {64.0f / 127.0f, -1.0f, 0.0f}},
        {VK_FORMAT_R8G8B8A8_UNORM, {255, 0, 51, 7}, {1.0f, 0.0f, 0.2f}},
        {VK_FORMAT_R8G8_UNORM, {255, 102}, {1.0f, 0.4f, 0.0f}},
        // A2B10G10R10: R bits 0-9 = 1023, G = 0, B = 341
        {VK_FORMAT_A2B10G10R10_UNORM_PACK32,
         {0xFF, 0x03, 0x50, 0x55},
         {1.0f, 0.0f, 341.0f / 1023.0f}},
    };
    for (const FormatCase& c : cases) {
        const VertexFormatInfo info = vertex_format_info(c.format);
        ASSERT_TRUE(info.supported) << c.format;
        ASSERT_EQ(info.size, c.bytes.size()) << c.format;
        float xyz[3];
        decode_vertex(c.format, reinterpret_cast<const std::byte*>(c.bytes.data()), xyz);
        for (int k = 0; k < 3; ++k)
            EXPECT_FLOAT_EQ(xyz[k], c.expected[k]) << "format " << c.format << " component " << k;

        // And through a real build with three copies of the vertex at a padded stride.
        Arena arena;
        const uint32_t stride = info.size * 2;
        std::vector<uint8_t> vb(3 * stride, 0xEE);
        for (int v = 0; v < 3; ++v) std::memcpy(vb.data() + v * stride, c.bytes.data(), info.size);
        const std::vector<uint8_t> idx = {0, 1, 2};
        VkClusterAccelerationStructureBuildTriangleClusterInfoNV bi{};
        bi.triangleCount = 1;
        bi.vertexCount = 3;
        bi.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_8BIT_NV;
        bi.indexBuffer = arena.put_vec(idx);
        bi.vertexBuffer = arena.put_vec(vb);
        bi.vertexBufferStride = uint16_t(stride);
        const ClusterObject o =
            build_triangle_cluster(arena.memory, bi, test::default_input(c.format),
                                   EngineProperties{}, 0);
        ASSERT_TRUE(o.ok) << c.format;
        EXPECT_TRUE(o.findings.empty()) << o.findings[0].message;
        const auto h = read_object_header(o.bytes).header;
        ASSERT_TRUE(h);
        EXPECT_EQ(h->vertex_format, uint32_t(c.format));
        float stored[3];
        decode_position(o.bytes, *h, 2, stored);
        for (int k = 0; k < 3; ++k) EXPECT_EQ(bits_of(stored[k]), bits_of(xyz[k])) << c.format;
    }
}

TEST(VertexFormat, UnsupportedFormatIsAFindingAndNoObject) {
    EXPECT_FALSE(vertex_format_info(VK_FORMAT_R8_UNORM).supported);
    Arena arena;
    const test::Mesh m = test::grid(2);
    auto info = test::cluster_info(arena, m);
    const ClusterObject o =
        build_triangle_cluster(arena.memory, info, test::default_input(VK_FORMAT_D32_SFLOAT),
                               EngineProperties{}, 3);
    EXPECT_FALSE(o.ok);
    EXPECT_TRUE(
        has_rule(o.findings,
                 "VUID-VkClusterAccelerationStructureTriangleClusterInputNV-vertexFormat-10439"));
}

// A hostile trace's format past VkFormat's range (0x7FFFFFFF) is the same finding, found by the
// field's bits (under UBSan, loading it as a VkFormat stopped the check itself).
TEST(VertexFormat, AFormatPastTheEnumsRangeIsAFindingAndNoObject) {
    EXPECT_FALSE(vertex_format_info(0xffffffffu).supported);
    Arena arena;
    const test::Mesh m = test::grid(2);
    auto info = test::cluster_info(arena, m);
    auto input = test::default_input(VK_FORMAT_R32G32B32_SFLOAT);
    common::set_enum_bits(input.vertexFormat, 0xffffffffu);
    const ClusterObject o =
        build_triangle_cluster(arena.memory, info, input, EngineProperties{}, 3);
    EXPECT_FALSE(o.ok);
    const char* rule =
        "VUID-VkClusterAccelerationStructureTriangleClusterInputNV-vertexFormat-10439";
    ASSERT_TRUE(has_rule(o.findings, rule));
    for (const Finding& f : o.findings)
        if (f.rule == rule)
            EXPECT_NE(f.message.find("vertexFormat -1 lacks"), std::string::npos) << f.message;
}

}  // namespace
}  // namespace clastrace::engine
