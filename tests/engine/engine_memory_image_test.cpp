// SPDX-License-Identifier: Apache-2.0
#include "clastrace/engine/memory_image.h"

#include <gtest/gtest.h>

#include <limits>

namespace clastrace::engine {
namespace {

TEST(MemoryImage, ReadWriteInsideRegion) {
    MemoryImage m;
    m.add_region(0x1000, 64, 0, "buf");
    m.write<uint32_t>(0x1010, 0xDEADBEEFu, {"x", 0});
    EXPECT_EQ(m.read<uint32_t>(0x1010, {"x", 0}), 0xDEADBEEFu);
    EXPECT_EQ(m.read<uint32_t>(0x1000 + 60, {"x", 0}), 0u);
}

TEST(MemoryImage, FaultNamesAddressFieldAndOp) {
    MemoryImage m;
    m.add_region(0x1000, 64, 0, "buf");
    try {
        (void)m.read<uint64_t>(0x1000 + 60, {"srcInfosArray[3].vertexBuffer", 3});
        FAIL() << "no fault";
    } catch (const MemoryFault& f) {
        EXPECT_EQ(f.address, 0x1000u + 60);
        EXPECT_EQ(f.op_index, 3);
        EXPECT_EQ(f.field, "srcInfosArray[3].vertexBuffer");
        EXPECT_NE(f.message.find("0x103c"), std::string::npos) << f.message;
        EXPECT_NE(f.message.find("srcInfosArray[3].vertexBuffer"), std::string::npos);
        EXPECT_NE(f.message.find("op 3"), std::string::npos);
    }
    EXPECT_THROW((void)m.read<uint8_t>(0xFFF, {"x", 1}), MemoryFault);
    EXPECT_THROW((void)m.read<uint8_t>(0x1040, {"x", 1}), MemoryFault);
    EXPECT_THROW((void)m.read<uint8_t>(0, {"x", 1}), MemoryFault);
}

// Each access kind says what it did and why the bytes are not there.
TEST(MemoryImage, FaultSaysReadOrWriteAndWhy) {
    MemoryImage m;
    m.add_region(0x1000, 64, 0, "buf");
    auto message = [&](auto access) {
        try {
            access();
        } catch (const MemoryFault& f) {
            return f.message;
        }
        return std::string("no fault");
    };
    auto contains = [](const std::string& text, const char* part) {
        return text.find(part) != std::string::npos;
    };
    EXPECT_TRUE(contains(message([&] {
                             (void)m.read_bytes(0, 4, {"x", 0});
                         }),
                         "null device address read"));
    EXPECT_TRUE(contains(message([&] {
                             (void)m.write_bytes(0, 4, {"x", 0});
                         }),
                         "null device address write"));
    EXPECT_TRUE(contains(message([&] {
                             (void)m.read_bytes(0x9000, 4, {"x", 0});
                         }),
                         "read from an address outside every memory region"));
    EXPECT_TRUE(contains(message([&] {
                             m.zero_bytes(0x9000, 4, {"x", 0});
                         }),
                         "write to an address outside every memory region"));
    EXPECT_TRUE(contains(message([&] {
                             (void)m.read_bytes(0x1038, 16, {"x", 0});
                         }),
                         "read runs off the end of region 'buf' [0x1000, +64)"));
    EXPECT_TRUE(contains(message([&] {
                             (void)m.write_bytes(0x1038, 16, {"x", 0});
                         }),
                         "write runs off the end of region 'buf' [0x1000, +64)"));
    EXPECT_EQ(message([&] { m.zero_bytes(0x1000, 64, {"x", 0}); }), "no fault");
}

TEST(MemoryImage, SizeWrappingTwoToThe64IsAFault) {
    MemoryImage m;
    m.add_region(0x1000, 64, 0, "buf");
    EXPECT_THROW((void)m.read_bytes(0x1008, std::numeric_limits<uint64_t>::max() - 4, {"x", 0}),
                 MemoryFault);
    EXPECT_THROW((void)m.read_bytes(0x1008, std::numeric_limits<uint64_t>::max(), {"x", 0}),
                 MemoryFault);
}

TEST(MemoryImage, RegionEndingAtTopOfAddressSpace) {
    MemoryImage m;
    const uint64_t base = std::numeric_limits<uint64_t>::max() - 15;
    m.add_region(base, 16, 0, "top");
    EXPECT_NO_THROW((void)m.read_bytes(base, 16, {"x", 0}));
    EXPECT_THROW((void)m.read_bytes(base + 8, 16, {"x", 0}), MemoryFault);
    EXPECT_THROW(m.add_region(base + 8, 16, 0, "over"), MemoryFault);
    EXPECT_THROW(m.add_region(std::numeric_limits<uint64_t>::max(), 2, 0, "wrap"), MemoryFault);
}

TEST(MemoryImage, OverlappingRegionsRejected) {
    MemoryImage m;
    m.add_region(0x1000, 0x100, 0, "a");
    EXPECT_THROW(m.add_region(0x10FF, 0x10, 0, "b"), MemoryFault);
    EXPECT_THROW(m.add_region(0x0F00, 0x101, 0, "c"), MemoryFault);
    EXPECT_THROW(m.add_region(0x2000, 0, 0, "empty"), MemoryFault);
    EXPECT_NO_THROW(m.add_region(0x1100, 0x10, 0, "adjacent"));
    EXPECT_EQ(m.find_region(0x1100)->label, "adjacent");
    EXPECT_EQ(m.find_region(0x10FF)->label, "a");
}

TEST(MemoryImage, StridedAddressPackedAndStrided) {
    VkStridedDeviceAddressRegionKHR r{0x1000, 0, 64};
    EXPECT_EQ(MemoryImage::strided_address(r, 3, 8, {"a", 0}), 0x1000u + 24);
    r.stride = 16;
    EXPECT_EQ(MemoryImage::strided_address(r, 3, 8, {"a", 0}), 0x1000u + 48);
    EXPECT_THROW(MemoryImage::strided_address(r, 4, 8, {"a", 0}),
                 MemoryFault);  // beyond region size
    r.size = 0;                 // unbounded
    EXPECT_EQ(MemoryImage::strided_address(r, 4, 8, {"a", 0}), 0x1000u + 64);
}

TEST(MemoryImage, StrideOverflowIsAFault) {
    VkStridedDeviceAddressRegionKHR r{0x1000, std::numeric_limits<uint64_t>::max() / 2, 0};
    EXPECT_THROW(MemoryImage::strided_address(r, 3, 8, {"a", 2}), MemoryFault);
    VkStridedDeviceAddressNV a{std::numeric_limits<uint64_t>::max() - 8, 16};
    EXPECT_THROW(MemoryImage::strided_address(a, 1, 4, {"a", 2}), MemoryFault);
    MemoryImage m;
    m.add_region(0x1000, 64, 0, "buf");
    EXPECT_THROW((void)m.read_array(0x1000, std::numeric_limits<uint64_t>::max(), 16, 4, {"a", 0}),
                 MemoryFault);
    EXPECT_THROW((void)m.read_array(0x1000, 5, 16, 4, {"a", 0}), MemoryFault);
    EXPECT_EQ(m.read_array(0x1000, 4, 16, 4, {"a", 0}).size(), 52u);
    EXPECT_EQ(m.read_array(0x1000, 4, 0, 4, {"a", 0}).size(), 16u);
}

}  // namespace
}  // namespace clastrace::engine
