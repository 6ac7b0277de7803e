// SPDX-License-Identifier: Apache-2.0
// The invariants of MemoryImage (with its regions' page accounting) and ObjectDirectory hold
// over real use, and a state broken on purpose fails them and aborts CLASTRACE_DEBUG_ASSERT.
#include "clastrace/common/debug_assert.h"
#include "clastrace/engine/memory_image.h"
#include "clastrace/engine/object_directory.h"

#include <gtest/gtest.h>

#include <random>
#include <vector>

static_assert(CLASTRACE_DEBUG_LEVEL == 1, "this test compiles the debug checks in");

namespace clastrace::engine {

struct ObjectDirectoryTestAccess {
    static void mark_moved_while_live(ObjectDirectory& directory, uint64_t address) {
        directory.moved_to_[address] = address + 256;
    }
    static void shrink_to_nothing(ObjectDirectory& directory, uint64_t address) {
        directory.live_.at(address).size = 0;
    }
};

namespace {

constexpr uint64_t kBase = 0x10000;
constexpr uint64_t kRegionBytes = 64 * RegionBytes::kPageBytes;

TEST(MemoryImageInvariants, HoldOverRandomAddsWritesZerosAndRemovals) {
    std::mt19937_64 random(18);
    MemoryImage image;
    std::vector<bool> present(16, false);
    for (int op = 0; op < 3000; ++op) {
        const uint64_t slot = random() % present.size(), base = kBase + slot * 2 * kRegionBytes;
        const uint64_t offset = random() % kRegionBytes,
                       size = 1 + random() % (kRegionBytes - offset);
        if (!present[slot]) {
            image.add_region(base, kRegionBytes, 0, "region");
            present[slot] = true;
        } else if (random() % 8 == 0) {
            image.remove_region(base);
            present[slot] = false;
        } else if (random() % 3 == 0) {
            image.zero_bytes(base + offset, size, {"zero"});
        } else {
            image.write_bytes(base + offset, size, {"write"})[0] = std::byte{1};
        }
        ASSERT_TRUE(image.invariants_hold()) << "after operation " << op;
    }
    EXPECT_GT(image.resident_bytes(), 0u);
}

TEST(MemoryImageInvariants, OverlappingRegionBreaksThem) {
    MemoryImage image;
    image.add_region(kBase, kRegionBytes, 0, "first");
    image.add_region(kBase + kRegionBytes, kRegionBytes, 0, "second");
    ASSERT_TRUE(image.invariants_hold());
    image.find_region(kBase)->size = kRegionBytes + 1;  // a caller bug: the regions now overlap
    EXPECT_FALSE(image.invariants_hold());
    EXPECT_DEATH(CLASTRACE_DEBUG_ASSERT(image.invariants_hold()),
                 "invariant broken: image.invariants_hold\\(\\)");
}

TEST(MemoryImageInvariants, RegionKeyedAwayFromItsBaseBreaksThem) {
    MemoryImage image;
    image.add_region(kBase, kRegionBytes, 0, "region");
    image.find_region(kBase)->base = kBase + 8;
    EXPECT_FALSE(image.invariants_hold());
}

TEST(ObjectDirectoryInvariants, HoldOverBuildsMovesAndForgets) {
    std::mt19937_64 random(18);
    ObjectDirectory directory;
    const std::vector<std::byte> bytes(64, std::byte{7});
    for (int op = 0; op < 2000; ++op) {
        const uint64_t address = kBase + 256 * (random() % 32);
        switch (random() % 3) {
        case 0: directory.record_built(address, ObjectType(1 + random() % 3), bytes); break;
        case 1: directory.record_moved_away(address, address + 256); break;
        default: directory.forget(address, address + 256 * (random() % 4));
        }
        ASSERT_TRUE(directory.invariants_hold()) << "after operation " << op;
    }
}

// Replay's runs ahead stand only where a run's directory answers lookup() as the replay's does;
// lookup() names a moved object's destination, so two moves of one address to different places
// are not the same entry.
TEST(ObjectDirectorySameEntry, MovedAwayAgreesOnlyOnTheSameDestination) {
    const std::vector<std::byte> bytes(64, std::byte{7});
    ObjectDirectory a, b;
    EXPECT_TRUE(a.same_entry(b, kBase));  // both know nothing of it
    a.record_built(kBase, ObjectType::kTriangleCluster, bytes);
    EXPECT_FALSE(a.same_entry(b, kBase));
    b.copy_entry(a, kBase);
    EXPECT_TRUE(a.same_entry(b, kBase));
    a.record_moved_away(kBase, kBase + 256);
    b.record_moved_away(kBase, kBase + 512);
    EXPECT_FALSE(a.same_entry(b, kBase));
    b.record_moved_away(kBase, kBase + 256);
    EXPECT_TRUE(a.same_entry(b, kBase));
}

TEST(ObjectDirectoryInvariants, LiveAndMovedAwayAtOnceBreaksThem) {
    ObjectDirectory directory;
    const std::vector<std::byte> bytes(64, std::byte{7});
    directory.record_built(kBase, ObjectType::kTriangleCluster, bytes);
    ASSERT_TRUE(directory.invariants_hold());
    ObjectDirectoryTestAccess::mark_moved_while_live(directory, kBase);
    EXPECT_FALSE(directory.invariants_hold());
    EXPECT_DEATH(CLASTRACE_DEBUG_ASSERT(directory.invariants_hold()), "invariant broken");
}

TEST(ObjectDirectoryInvariants, EmptyLiveObjectBreaksThem) {
    ObjectDirectory directory;
    const std::vector<std::byte> bytes(64, std::byte{7});
    directory.record_built(kBase, ObjectType::kTriangleCluster, bytes);
    ObjectDirectoryTestAccess::shrink_to_nothing(directory, kBase);
    EXPECT_FALSE(directory.invariants_hold());
}

}  // namespace
}  // namespace clastrace::engine
