// SPDX-License-Identifier: Apache-2.0
// SegmentStore (the synchronization model's address map) against two references over random
// operation streams: the std::map-keyed store it replaced, written out here as it was (same
// splits, same merges, same visiting order), and a per-byte model that knows nothing of
// segments. The body is a list of operation ids, so any visit to the wrong bytes, a missed
// copy on a split or a body shared by two segments shows up as a different list.
#include <gtest/gtest.h>

#include <cstdint>
#include <map>
#include <optional>
#include <random>
#include <string>
#include <tuple>
#include <vector>

#include "segment_store.h"

namespace clastrace::replay::detail {
namespace {

struct Ids {
    std::vector<int> ids;
    void clear() { ids.clear(); }
    friend bool operator==(const Ids&, const Ids&) = default;
};

using Visit =
    std::tuple<uint64_t, uint64_t, bool, std::vector<int>>;  // begin, end, fresh, body after

// The old store: std::map<begin, Segment{end, body}>, with the replay's original record() loop.
class MapStore {
public:
    template <class Fresh, class Touch>
    void update(uint64_t begin, uint64_t end, bool merge, Fresh&& fresh, Touch&& touch) {
        if (end <= begin) return;
        auto it = map_.upper_bound(begin);
        if (it != map_.begin()) {
            auto prev = std::prev(it);
            if (prev->second.end > begin) {
                if (prev->first < begin) {
                    Seg tail = prev->second;
                    prev->second.end = begin;
                    it = map_.emplace_hint(it, begin, std::move(tail));
                } else {
                    it = prev;
                }
            }
        }
        auto first = map_.end();
        uint64_t cursor = begin;
        while (cursor < end) {
            if (it == map_.end() || it->first > cursor) {
                const uint64_t gap_end = it == map_.end() ? end : std::min(end, it->first);
                Seg s;
                s.end = gap_end;
                fresh(s.body, cursor, gap_end);
                it = map_.emplace_hint(it, cursor, std::move(s));
                if (first == map_.end()) first = it;
                cursor = gap_end;
                ++it;
                continue;
            }
            if (it->second.end > end) {
                Seg tail = it->second;
                it->second.end = end;
                map_.emplace_hint(std::next(it), end, std::move(tail));
            }
            if (first == map_.end()) first = it;
            touch(it->second.body, it->first, it->second.end);
            cursor = it->second.end;
            ++it;
        }
        if (merge && std::next(first) != it) {
            first->second.end = end;
            map_.erase(std::next(first), it);
        }
    }
    void split_at(uint64_t at) {
        auto it = map_.upper_bound(at);
        if (it == map_.begin()) return;
        --it;
        if (it->first >= at || it->second.end <= at) return;
        Seg tail = it->second;
        it->second.end = at;
        map_.emplace_hint(std::next(it), at, std::move(tail));
    }
    template <class Drop>
    void erase_if(Drop&& drop, uint64_t lo, uint64_t hi) {
        for (auto it = map_.begin(); it != map_.end();) {
            if (it->second.end > lo && it->first < hi &&
                drop(it->second.body, it->first, it->second.end))
                it = map_.erase(it);
            else
                ++it;
        }
    }
    std::vector<std::tuple<uint64_t, uint64_t, std::vector<int>>> list() const {
        std::vector<std::tuple<uint64_t, uint64_t, std::vector<int>>> out;
        for (const auto& [b, s] : map_) out.emplace_back(b, s.end, s.body.ids);
        return out;
    }

private:
    struct Seg {
        uint64_t end = 0;
        Ids body;
    };
    std::map<uint64_t, Seg> map_;
};

std::vector<std::tuple<uint64_t, uint64_t, std::vector<int>>> list_of(SegmentStore<Ids>& store) {
    std::vector<std::tuple<uint64_t, uint64_t, std::vector<int>>> out;
    store.for_each([&](Ids& body, uint64_t b, uint64_t e) { out.emplace_back(b, e, body.ids); });
    return out;
}

// Drops a segment by its contents alone, so every store decides the same.
bool drop_rule(const Ids& body, int salt) {
    uint64_t h = uint64_t(salt) * 0x9E3779B97F4A7C15ull;
    for (int id : body.ids) h = (h ^ uint64_t(id)) * 0x100000001B3ull;
    return h % 3 == 0;
}

void run_stream(uint32_t seed, uint64_t space, int ops, int bytes_every = 1) {
    std::mt19937 rng(seed);
    SegmentStore<Ids> store;
    MapStore reference;
    std::vector<std::optional<std::vector<int>>> bytes(space);  // per-byte model
    for (int op = 1; op <= ops; ++op) {
        const int kind = int(rng() % 10);
        uint64_t a = rng() % space, b = rng() % (space + 1);
        if (rng() % 4 == 0)
            b = std::min<uint64_t>(space, a + 1 + rng() % 4);  // short accesses are common
        if (a > b) std::swap(a, b);
        SCOPED_TRACE("seed " + std::to_string(seed) + " op " + std::to_string(op) + " kind " +
                     std::to_string(kind) + " [" + std::to_string(a) + "," + std::to_string(b) +
                     ")");
        if (kind < 7) {
            const bool merge = kind < 3;  // a write: every touched segment ends up equal, then one
            std::vector<Visit> seen_new, seen_ref;
            auto make = [&](std::vector<Visit>* seen) {
                auto fresh = [op, seen](Ids& body, uint64_t s, uint64_t e) {
                    EXPECT_TRUE(body.ids.empty()) << "a fresh body must come cleared";
                    body.ids = {op};
                    seen->emplace_back(s, e, true, body.ids);
                };
                auto touch = [op, merge, seen](Ids& body, uint64_t s, uint64_t e) {
                    if (merge)
                        body.ids = {op};
                    else
                        body.ids.push_back(op);
                    seen->emplace_back(s, e, false, body.ids);
                };
                return std::make_pair(fresh, touch);
            };
            auto [f1, t1] = make(&seen_new);
            auto [f2, t2] = make(&seen_ref);
            store.update(a, b, merge, f1, t1);
            reference.update(a, b, merge, f2, t2);
            ASSERT_EQ(seen_new, seen_ref) << "visits differ";
            for (uint64_t x = a; x < b; ++x) {
                if (!bytes[x] || merge)
                    bytes[x] = std::vector<int>{op};
                else
                    bytes[x]->push_back(op);
            }
        } else if (kind < 8) {
            store.split_at(a);
            reference.split_at(a);
        } else {
            const int salt = op;
            store.erase_if([&](Ids& body, uint64_t, uint64_t) { return drop_rule(body, salt); }, a,
                           b);
            reference.erase_if([&](Ids& body, uint64_t, uint64_t) { return drop_rule(body, salt); },
                               a, b);
            // Which bytes go depends on how they are grouped into segments, which the per-byte
            // model does not know: it takes the map store's answer (checked just below).
            for (uint64_t x = 0; x < space; ++x) bytes[x].reset();
            for (const auto& [s, e, ids] : reference.list())
                for (uint64_t x = s; x < e; ++x) bytes[x] = ids;
        }
        const auto got = list_of(store);
        ASSERT_EQ(got, reference.list()) << "segment lists differ";
        ASSERT_EQ(store.size(), got.size());
        if (op % bytes_every != 0 && op != ops) continue;
        std::vector<std::optional<std::vector<int>>> from_store(space);
        uint64_t last_end = 0;
        for (const auto& [s, e, ids] : got) {
            ASSERT_LT(s, e) << "empty segment";
            ASSERT_LE(last_end, s) << "segments overlap or are out of order";
            last_end = e;
            for (uint64_t x = s; x < e; ++x) from_store[x] = ids;
        }
        ASSERT_EQ(from_store, bytes) << "per-byte contents differ";
    }
}

TEST(SegmentStore, MatchesMapStoreAndPerByteModelOnRandomStreams) {
    for (uint32_t seed = 1; seed <= 300; ++seed) run_stream(seed, 64 + seed % 64, 300);
}

TEST(SegmentStore, MatchesOnLongStreamsOverWideSpace) {
    for (uint32_t seed = 1000; seed < 1006; ++seed) run_stream(seed, 4096, 2000, 25);
}

// A sorted walk (begin_sorted ... end_sorted, as record_accesses feeds a command's disjoint
// accesses) leaves the store and visits exactly what the same updates one by one do, and
// size() counts the segments in the middle of the walk too.
TEST(SegmentStore, SortedWalkMatchesUpdatesOneByOne) {
    for (uint32_t seed = 1; seed <= 400; ++seed) {
        std::mt19937 rng(seed);
        const uint64_t space = 64 + seed % 200;
        SegmentStore<Ids> walked, single;
        int op = 0;
        for (int command = 0; command < 40; ++command) {
            // Ascending disjoint ranges, some touching, some with gaps, short and long.
            std::vector<std::tuple<uint64_t, uint64_t, bool>> ranges;
            uint64_t at = rng() % 8;
            while (at < space && ranges.size() < 12) {
                const uint64_t end =
                    std::min<uint64_t>(space, at + 1 + rng() % (rng() % 3 ? 6 : 40));
                ranges.emplace_back(at, end, rng() % 3 == 0);
                at = end + (rng() % 3 ? 0 : rng() % 12);
            }
            SCOPED_TRACE("seed " + std::to_string(seed) + " command " + std::to_string(command));
            std::vector<Visit> seen_walked, seen_single;
            std::vector<std::size_t> sizes_walked, sizes_single;
            walked.begin_sorted();
            for (const auto& [b, e, merge] : ranges) {
                ++op;
                for (auto* side : {&walked, &single}) {
                    std::vector<Visit>* seen = side == &walked ? &seen_walked : &seen_single;
                    const int id = op;
                    const bool m = merge;
                    side->update(
                        b, e, m,
                        [id, seen](Ids& body, uint64_t s, uint64_t x) {
                            body.ids = {id};
                            seen->emplace_back(s, x, true, body.ids);
                        },
                        [id, m, seen](Ids& body, uint64_t s, uint64_t x) {
                            if (m)
                                body.ids = {id};
                            else
                                body.ids.push_back(id);
                            seen->emplace_back(s, x, false, body.ids);
                        });
                    (side == &walked ? sizes_walked : sizes_single).push_back(side->size());
                }
            }
            walked.end_sorted();
            ASSERT_EQ(seen_walked, seen_single) << "visits differ";
            ASSERT_EQ(sizes_walked, sizes_single) << "sizes during the walk differ";
            ASSERT_EQ(list_of(walked), list_of(single)) << "segment lists differ";
            ASSERT_TRUE(walked.invariants_hold());
            // Now and then something other than a walk between two walks.
            if (rng() % 4 == 0) {
                const uint64_t x = rng() % space;
                walked.split_at(x);
                single.split_at(x);
            }
        }
    }
}

TEST(SegmentStore, ForEachRangeVisitsExactlyTheSegmentsMeetingIt) {
    SegmentStore<Ids> store;
    auto none = [](Ids&, uint64_t, uint64_t) {};
    auto mark = [](int id) { return [id](Ids& b, uint64_t, uint64_t) { b.ids = {id}; }; };
    store.update(10, 20, true, mark(1), none);
    store.update(30, 40, true, mark(2), none);
    store.update(40, 50, true, mark(3), none);
    std::vector<int> seen;
    store.for_each([&](Ids& b, uint64_t, uint64_t) { seen.push_back(b.ids[0]); }, 20, 41);
    EXPECT_EQ(seen, (std::vector<int>{2, 3}));  // [10,20) ends at 20: outside
    seen.clear();
    store.for_each([&](Ids& b, uint64_t, uint64_t) { seen.push_back(b.ids[0]); }, 19, 30);
    EXPECT_EQ(seen, (std::vector<int>{1}));  // [30,40) begins at 30: outside
}

TEST(SegmentStore, ReleasedBodiesComeBackClearedAndKeepTheirCapacity) {
    SegmentStore<Ids> store;
    auto fill = [](Ids& b, uint64_t, uint64_t) { b.ids.assign(100, 7); };
    auto none = [](Ids&, uint64_t, uint64_t) {};
    store.update(0, 10, true, fill, none);
    store.erase_if([](Ids&, uint64_t, uint64_t) { return true; });
    EXPECT_EQ(store.size(), 0u);
    std::size_t capacity = 0;
    store.update(
        0, 10, true,
        [&](Ids& b, uint64_t, uint64_t) {
            EXPECT_TRUE(b.ids.empty());
            capacity = b.ids.capacity();
        },
        none);
    EXPECT_GE(capacity, 100u);
}

}  // namespace
}  // namespace clastrace::replay::detail
