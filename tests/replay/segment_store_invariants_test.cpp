// SPDX-License-Identifier: Apache-2.0
// SegmentStore with its debug checks compiled in: random updates, splits and erasures keep every
// invariant, and a store whose entries are broken on purpose aborts at the next mutation.
#include <gtest/gtest.h>

#include <cstdint>
#include <random>
#include <vector>

#include "segment_store.h"

static_assert(CLASTRACE_DEBUG_LEVEL == 1, "this test compiles SegmentStore's checks in");

namespace clastrace::replay::detail {

template <class Body>
struct SegmentStoreTestAccess {
    static void overlap_first_two(SegmentStore<Body>& store) {
        store.entries_[0].end = store.entries_[1].begin + 1;
        store.ends_[0] = store.entries_[0].end;
    }
    static void empty_second(SegmentStore<Body>& store) {
        store.entries_[1].end = store.entries_[1].begin;
        store.ends_[1] = store.entries_[1].end;
    }
};

namespace {

struct Ids {
    std::vector<int> ids;
    void clear() { ids.clear(); }
};
using Store = SegmentStore<Ids>;
using Access = SegmentStoreTestAccess<Ids>;

void add(Store& store, uint64_t begin, uint64_t end, int id, bool merge) {
    store.update(
        begin, end, merge, [&](Ids& b, uint64_t, uint64_t) { b.ids = {id}; },
        [&](Ids& b, uint64_t, uint64_t) { b.ids.push_back(id); });
}

TEST(SegmentStoreInvariants, HoldOverRandomUpdatesSplitsAndErasures) {
    std::mt19937_64 random(18);
    Store store;
    for (int op = 0; op < 4000; ++op) {
        const uint64_t begin = random() % 512, end = begin + 1 + random() % 64;
        switch (random() % 4) {
        case 0:
        case 1: add(store, begin, end, op, random() % 2 == 0); break;
        case 2: store.split_at(begin); break;
        default:
            store.erase_if([&](Ids& b, uint64_t, uint64_t) { return b.ids.size() % 3 == 0; }, begin,
                           end);
        }
        ASSERT_TRUE(store.invariants_hold()) << "after operation " << op;
    }
    EXPECT_GT(store.size(), 10u);
}

TEST(SegmentStoreInvariants, FullCheckSeesOverlapAndEmptySegments) {
    Store overlapping;
    add(overlapping, 0, 16, 1, false);
    add(overlapping, 16, 32, 2, false);
    ASSERT_TRUE(overlapping.invariants_hold());
    Access::overlap_first_two(overlapping);
    EXPECT_FALSE(overlapping.invariants_hold());

    Store empty;
    add(empty, 0, 16, 1, false);
    add(empty, 16, 32, 2, false);
    Access::empty_second(empty);
    EXPECT_FALSE(empty.invariants_hold());
}

TEST(SegmentStoreInvariantsDeathTest, MutationNextToOverlappingSegmentsAborts) {
    Store store;
    add(store, 0, 16, 1, false);
    add(store, 16, 32, 2, false);
    Access::overlap_first_two(store);
    EXPECT_DEATH(store.split_at(8), "segment_store\\.h:[0-9]+: invariant broken: entries_hold");
}

TEST(SegmentStoreInvariantsDeathTest, UpdateOverAnEmptySegmentAborts) {
    Store store;
    add(store, 0, 16, 1, false);
    add(store, 16, 32, 2, false);
    add(store, 32, 48, 3, false);
    Access::empty_second(store);
    EXPECT_DEATH(add(store, 8, 40, 4, false), "invariant broken: entries_hold");
}

TEST(SegmentStoreInvariants, HoldOverRandomSortedWalks) {
    std::mt19937_64 random(23);
    Store store;
    for (int walk = 0; walk < 1000; ++walk) {
        store.begin_sorted();
        uint64_t at = random() % 64;
        const int ranges = 1 + int(random() % 12);
        for (int range = 0; range < ranges && at < 1024; ++range) {
            const uint64_t end = at + 1 + random() % (random() % 4 ? 8 : 96);
            add(store, at, end, walk, random() % 3 == 0);
            at = end + (random() % 2 ? 0 : random() % 40);
        }
        store.end_sorted();
        ASSERT_TRUE(store.invariants_hold()) << "after walk " << walk;
        if (random() % 3 == 0)
            store.erase_if([&](Ids& b, uint64_t, uint64_t) { return b.ids.size() % 4 == 0; });
    }
    EXPECT_GT(store.size(), 10u);
}

TEST(SegmentStoreInvariantsDeathTest, SortedWalkGoingBackAborts) {
    Store store;
    store.begin_sorted();
    add(store, 16, 32, 1, false);
    EXPECT_DEATH(add(store, 8, 12, 2, false), "segment_store\\.h:[0-9]+: invariant broken");
}

}  // namespace
}  // namespace clastrace::replay::detail
