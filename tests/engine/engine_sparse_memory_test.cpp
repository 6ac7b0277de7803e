// SPDX-License-Identifier: Apache-2.0
// The memory image costs the pages written, not the regions' sizes.
#include "clastrace/engine/memory_image.h"

#include <gtest/gtest.h>

#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cstring>
#include <utility>
#include <vector>

namespace clastrace::engine {
namespace {

constexpr uint64_t kPage = RegionBytes::kPageBytes;
constexpr uint64_t kGiB = 1ull << 30;

// Pages of [data, data + size) the OS holds in memory (an independent check of the accounting).
uint64_t os_resident_pages(const std::byte* data, uint64_t size) {
    const uint64_t os_page = uint64_t(sysconf(_SC_PAGESIZE));
    auto* begin = const_cast<std::byte*>(data);
    std::vector<unsigned char> vec((size + os_page - 1) / os_page);
    if (mincore(begin, size, vec.data()) != 0) return ~0ull;
    return uint64_t(std::count_if(vec.begin(), vec.end(), [](unsigned char c) { return c & 1; }));
}

std::vector<std::byte> pattern(size_t n, uint8_t seed) {
    std::vector<std::byte> v(n);
    for (size_t i = 0; i < n; ++i) v[i] = std::byte(uint8_t(seed + i * 7));
    return v;
}

void put(MemoryImage& m, uint64_t address, const std::vector<std::byte>& bytes) {
    std::memcpy(m.write_bytes(address, bytes.size(), {"test", -1}).data(), bytes.data(),
                bytes.size());
}

TEST(SparseMemoryImage, SixteenGiBRegionWithAFewKiBWrittenHoldsOnlyThosePages) {
    MemoryImage m;
    const uint64_t base = 0x100000000ull, size = 16 * kGiB;
    m.add_region(base, size, 0, "huge");
    EXPECT_EQ(m.reserved_bytes(), size);
    EXPECT_EQ(m.resident_bytes(), 0u);
    // Three writes: one at the start, one crossing a page boundary in the middle, one ending
    // at the region's last byte.
    const auto a = pattern(1000, 1), b = pattern(3000, 2), c = pattern(512, 3);
    put(m, base, a);
    const uint64_t middle = base + 8 * kGiB - 1000;  // crosses into the next page
    put(m, middle, b);
    put(m, base + size - c.size(), c);
    EXPECT_EQ(m.resident_bytes(), 4 * kPage);  // 1 + 2 + 1 pages
    const MemoryRegion* r = m.find_region(base);
    ASSERT_NE(r, nullptr);
    EXPECT_LE(os_resident_pages(r->bytes.data(), size) * uint64_t(sysconf(_SC_PAGESIZE)),
              4 * kPage);

    auto span = m.read_bytes(middle, b.size(), {"test", -1});
    EXPECT_TRUE(std::equal(span.begin(), span.end(), b.begin()));
    span = m.read_bytes(base + size - c.size(), c.size(), {"test", -1});
    EXPECT_TRUE(std::equal(span.begin(), span.end(), c.begin()));
    // Untouched memory reads as zeros, across many pages, and reading costs nothing.
    span = m.read_bytes(base + 4 * kGiB, 1 << 20, {"test", -1});
    EXPECT_TRUE(
        std::all_of(span.begin(), span.end(), [](std::byte x) { return x == std::byte{0}; }));
    EXPECT_EQ(m.resident_bytes(), 4 * kPage);
}

TEST(SparseMemoryImage, SpansAcrossPagesAreContiguousAndSurviveLaterAccesses) {
    MemoryImage m;
    m.add_region(0x1000, 64 * kPage, 0, "r");
    const auto first = pattern(3 * kPage + 17, 9);
    put(m, 0x1000 + kPage - 5, first);
    // A span taken before more writes elsewhere in the region stays valid and unchanged.
    auto held = m.read_bytes(0x1000 + kPage - 5, first.size(), {"test", -1});
    put(m, 0x1000 + 40 * kPage + 100, pattern(2 * kPage, 4));
    put(m, 0x1000 + 20 * kPage - 1, pattern(2, 5));
    EXPECT_TRUE(std::equal(held.begin(), held.end(), first.begin()));
    EXPECT_EQ(m.resident_bytes(), (5 + 3 + 2) * kPage);
}

TEST(SparseMemoryImage, ZeroingGivesWholePagesBackAndKeepsTheEdges) {
    MemoryImage m;
    const uint64_t base = 0x10000;
    m.add_region(base, 256 * kPage, 0, "r");
    const auto all = pattern(256 * kPage, 11);
    put(m, base, all);
    EXPECT_EQ(m.resident_bytes(), 256 * kPage);
    // Zero from mid-page 10 to mid-page 200: pages 11..199 go back, the edge pages stay.
    const uint64_t from = 10 * kPage + 100, to = 200 * kPage + 50;
    m.zero_bytes(base + from, to - from, {"fill", -1});
    EXPECT_EQ(m.resident_bytes(), (256 - 189) * kPage);
    auto s = m.read_bytes(base, 256 * kPage, {"test", -1});
    for (uint64_t i : {uint64_t(0), from - 1, to, 256 * kPage - 1}) EXPECT_EQ(s[i], all[i]) << i;
    for (uint64_t i : {from, 11 * kPage, 150 * kPage + 3, to - 1})
        EXPECT_EQ(s[i], std::byte{0}) << i;
    // Zeroing untouched memory allocates nothing.
    MemoryImage fresh;
    fresh.add_region(base, 4 * kGiB, 0, "scratch");
    fresh.zero_bytes(base + 3, 4 * kGiB - 3, {"fill", -1});
    EXPECT_EQ(fresh.resident_bytes(), 0u);
}

TEST(SparseMemoryImage, RemovedRegionsGiveTheirPagesAndAddressesBack) {
    MemoryImage m;
    m.add_region(0x100000, kGiB, 0, "a");
    m.add_region(0x100000 + kGiB, kPage, 0, "b");
    put(m, 0x100000 + 12345, pattern(9000, 1));
    put(m, 0x100000 + kGiB, pattern(10, 1));
    EXPECT_EQ(m.resident_bytes(), 4 * kPage);
    EXPECT_TRUE(m.remove_region(0x100000));
    EXPECT_FALSE(m.remove_region(0x100000));
    EXPECT_EQ(m.reserved_bytes(), kPage);
    EXPECT_EQ(m.resident_bytes(), kPage);
    EXPECT_EQ(m.find_region(0x100000 + 12345), nullptr);
    EXPECT_THROW((void)m.read_bytes(0x100000 + 12345, 1, {"test", -1}), MemoryFault);
    // The range can be bound again and reads zeros.
    m.add_region(0x100000, 2 * kPage, 0, "again");
    EXPECT_EQ(m.read<uint64_t>(0x100000 + 100, {"test", -1}), 0u);
}

// A served build's next image reuses the last one's bytes: same pages, as they were (the
// caller overwrites them), counted as written; bytes of another size are not used.
TEST(SparseMemoryImage, ReleasedStorageIsReusedAsIs) {
    MemoryImage first;
    first.add_region(0x100000, 3 * kPage, 0, "a");
    put(first, 0x100000 + 10, pattern(100, 3));
    std::vector<RegionBytes> storage = first.release_storage();
    EXPECT_TRUE(first.regions().empty());
    EXPECT_EQ(first.reserved_bytes(), 0u);
    ASSERT_EQ(storage.size(), 1u);
    const std::byte* pages = std::as_const(storage[0]).data();

    MemoryImage next;
    MemoryRegion& r = next.add_region(0x900000, 3 * kPage, 0, "b", std::move(storage[0]));
    EXPECT_EQ(static_cast<const RegionBytes&>(r.bytes).data(), pages);
    EXPECT_EQ(next.read_bytes(0x900000 + 10, 100, {"test", -1})[99], pattern(100, 3)[99]);
    EXPECT_EQ(next.resident_bytes(), kPage);

    RegionBytes other(kPage);
    MemoryRegion& fresh = next.add_region(0x200000, 2 * kPage, 0, "c", std::move(other));
    EXPECT_EQ(fresh.bytes.size(), 2 * kPage);
    EXPECT_EQ(next.read<uint64_t>(0x200000, {"test", -1}), 0u);  // zero-filled: the size differed
}

TEST(SparseMemoryImage, CopiesHoldTheSameBytesAndOnlyTheWrittenPages) {
    MemoryImage m;
    m.add_region(0x100000, kGiB, 0, "a");
    const auto bytes = pattern(5000, 7);
    put(m, 0x100000 + kGiB / 2, bytes);
    MemoryImage copy = m;
    EXPECT_EQ(copy.resident_bytes(), m.resident_bytes());
    auto s = copy.read_bytes(0x100000 + kGiB / 2, bytes.size(), {"test", -1});
    EXPECT_TRUE(std::equal(s.begin(), s.end(), bytes.begin()));
    put(copy, 0x100000 + kGiB / 2, pattern(5000, 99));  // independent storage
    s = m.read_bytes(0x100000 + kGiB / 2, bytes.size(), {"test", -1});
    EXPECT_TRUE(std::equal(s.begin(), s.end(), bytes.begin()));
    MemoryImage moved = std::move(copy);
    EXPECT_EQ(moved.read<uint8_t>(0x100000 + kGiB / 2, {"test", -1}), uint8_t(99));
}

TEST(SparseMemoryImage, ResidentLimitTurnsFurtherPagesIntoFaults) {
    MemoryImage m;
    m.add_region(0x100000, kGiB, 0, "a");
    m.set_resident_limit(2 * kPage);
    put(m, 0x100000, pattern(kPage + 1, 1));  // two pages
    put(m, 0x100000 + 10, pattern(100, 2));   // pages already held: no new cost
    try {
        put(m, 0x100000 + kGiB / 2, pattern(8, 3));
        FAIL() << "no fault";
    } catch (const MemoryFault& f) {
        EXPECT_NE(f.message.find("limit of 8192 resident bytes"), std::string::npos) << f.message;
    }
    EXPECT_EQ(m.resident_limit_faults(), 1u);
    EXPECT_EQ(m.resident_bytes(), 2 * kPage);
    m.zero_bytes(0x100000, 2 * kPage, {"fill", -1});  // giving pages back makes room again
    EXPECT_NO_THROW(put(m, 0x100000 + kGiB / 2, pattern(8, 3)));
}

TEST(SparseMemoryImage, RawRegionAccessCountsTheWholeRegion) {
    // add_region(...).bytes.data() hands out write access with no range: counted whole, so
    // the accounting stays an upper bound.
    MemoryImage m;
    MemoryRegion& r = m.add_region(0x1000, 10 * kPage + 3, 0, "raw");
    std::memset(r.bytes.data(), 0xAB, 16);
    EXPECT_EQ(m.resident_bytes(), 11 * kPage);
    EXPECT_EQ(m.read<uint8_t>(0x1000 + 15, {"test", -1}), 0xABu);
    const std::vector<std::byte> whole = r.bytes;
    EXPECT_EQ(whole.size(), 10 * kPage + 3);
}

// More live regions than the OS gives mappings (vm.max_map_count, 65530 by default). Linux
// usually merges adjacent anonymous mappings, so this often stays sparse throughout; where
// it does not, the regions past the limit are held densely (the dense_regions property says
// how many were) and must read and write like any other.
TEST(SparseMemoryImage, MoreRegionsThanTheOsHasMappingsStillWork) {
    MemoryImage m;
    constexpr uint64_t kRegions = 70000, kBase = 0x100000000ull;
    for (uint64_t i = 0; i < kRegions; ++i) m.add_region(kBase + i * 2 * kPage, 100, 0, "small");
    uint64_t dense = 0;
    for (uint64_t i = 0; i < kRegions; ++i) {
        m.write<uint64_t>(kBase + i * 2 * kPage + 8, i * 3 + 1, {"test", -1});
        dense += m.find_region(kBase + i * 2 * kPage)->bytes.dense();
    }
    for (uint64_t i = 0; i < kRegions; i += 997)
        EXPECT_EQ(m.read<uint64_t>(kBase + i * 2 * kPage + 8, {"test", -1}), i * 3 + 1);
    EXPECT_EQ(m.resident_bytes(), kRegions * kPage);  // one page each, dense or not
    m.zero_bytes(kBase + (kRegions - 1) * 2 * kPage, 100, {"fill", -1});
    EXPECT_EQ(m.read<uint64_t>(kBase + (kRegions - 1) * 2 * kPage + 8, {"test", -1}), 0u);
    RecordProperty("dense_regions", std::to_string(dense));
}

}  // namespace
}  // namespace clastrace::engine
