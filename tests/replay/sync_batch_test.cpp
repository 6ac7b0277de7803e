// SPDX-License-Identifier: Apache-2.0
// SyncModel::record_accesses keeps per-op array elements as one range: it must report
// exactly what record_access on each access reports (same hazards, order, fields, ranges).
#include <gtest/gtest.h>

#include <clastrace/replay/sync_model.h>

#include <algorithm>
#include <random>
#include <string>
#include <vector>

namespace clastrace::replay {
namespace {

struct Kind {
    StageMask stage;
    AccessMask access;
    bool write;
};
constexpr Kind kKinds[] = {
    {VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
     VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT, false},
    {VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
     VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR, false},
    {VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
     VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR, true},
    {VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT, true},
    {VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_READ_BIT, false},
};
constexpr const char* kArrays[] = {"srcInfosArray[", "dstAddressesArray[", "dstSizesArray["};
constexpr const char* kSuffixes[] = {"]", "].vertexBuffer"};

// One random stream fed to two models: per access, and per command.
struct TwoModels {
    SyncModel single{SyncOptions{1u << 20}}, batched{SyncOptions{1u << 20}};  // every report
    std::mt19937 rng;
    std::vector<std::string> names;  // outlive each command's Access list
    int shift = 0;                   // places are picked in [0, space) and shifted left by this
    explicit TwoModels(uint32_t seed) : rng(seed) {}
    int pick(int n) { return int(rng() % uint32_t(n)); }
    uint64_t place(uint64_t space) { return uint64_t(pick(int(space))) << shift; }

    std::vector<Access> command_accesses(uint64_t space) {
        std::vector<Access> out;
        names.clear();
        names.reserve(256);
        const int ops = 1 + pick(12);
        // Per-op fields; each array contiguous (sometimes not: a stride gap or a size change).
        struct Array {
            const char* prefix;
            const char* suffix;
            Kind kind;
            uint64_t base, bytes, gap;
        };
        std::vector<Array> arrays;
        const int n_arrays = 1 + pick(3);
        for (int a = 0; a < n_arrays; ++a) {
            const uint64_t bytes = 1 + uint64_t(pick(6));
            arrays.push_back({kArrays[pick(3)], kSuffixes[pick(2)], kKinds[pick(std::size(kKinds))],
                              place(space), bytes, pick(5) == 0 ? 1u : 0u});
        }
        const int first = pick(3) == 0 ? 0 : pick(20);
        for (int i = 0; i < ops; ++i) {
            for (const Array& a : arrays) {
                if (pick(12) == 0) continue;  // an op without this field
                const uint64_t begin = a.base + uint64_t(i) * (a.bytes + a.gap);
                const uint64_t bytes = pick(15) == 0 ? a.bytes + 1 : a.bytes;
                names.push_back(a.prefix + std::to_string(first + i + (pick(20) == 0 ? 1 : 0)) +
                                a.suffix);
                out.push_back({{begin, begin + bytes},
                               a.kind.stage,
                               a.kind.access,
                               a.kind.write,
                               names.back()});
            }
            if (pick(3) == 0) {  // a field without an index, e.g. an object write
                const Kind& k = kKinds[pick(std::size(kKinds))];
                const uint64_t begin = place(space);
                names.push_back(pick(2) ? "scratchData"
                                        : "dstImplicitData[op " + std::to_string(i) + "]");
                out.push_back({{begin, begin + 1 + uint64_t(pick(8))},
                               k.stage,
                               k.access,
                               k.write,
                               names.back()});
            }
        }
        return out;
    }

    void run(int commands, uint64_t space) {
        single.begin_submission(0, 0);
        batched.begin_submission(0, 0);
        for (int c = 0; c < commands; ++c) {
            const CommandRef ref{0, 0, 1, uint32_t(c), "cmd"};
            const int roll = pick(10);
            if (roll < 6) {
                const std::vector<Access> accesses = command_accesses(space);
                for (const Access& a : accesses) single.record_access(ref, a);
                batched.record_accesses(ref, accesses);
            } else {
                // Barriers, often buffer barriers whose edges cut through element runs.
                std::vector<MemoryBarrier> mem;
                std::vector<BufferBarrier> buf;
                const Kind& from = kKinds[pick(std::size(kKinds))];
                const Kind& to = kKinds[pick(std::size(kKinds))];
                const MemoryBarrier m{from.stage, from.write ? from.access : 0, to.stage,
                                      to.access};
                if (pick(2)) {
                    const uint64_t begin = place(space);
                    buf.push_back({m, {begin, begin + 1 + uint64_t(pick(24))}});
                } else {
                    mem.push_back(m);
                }
                const DependencyInfo dep{mem, buf, 0};
                single.pipeline_barrier(ref, dep);
                batched.pipeline_barrier(ref, dep);
            }
        }
        single.end_submission();
        batched.end_submission();
    }
};

std::vector<std::string> formatted(const SyncModel& m) {
    std::vector<std::string> out;
    for (const HazardReport& h : m.hazards()) out.push_back(h.format());
    return out;
}

// The later access of each report: command, field and bytes.
std::vector<std::string> later_accesses(const SyncModel& m) {
    std::vector<std::string> out;
    for (const HazardReport& h : m.hazards())
        out.push_back(std::to_string(h.later.command.command) + " " + h.later.field + " " +
                      std::to_string(h.later.range.begin) + "-" +
                      std::to_string(h.later.range.end));
    return out;
}

TEST(SyncBatch, RecordAccessesReportsExactlyWhatRecordAccessReports) {
    std::size_t hazards = 0;
    for (uint32_t seed = 1; seed <= 300; ++seed) {
        TwoModels t(seed);
        t.run(40, 160);
        // Reports come in the same order of later accesses; the reports of one later access
        // may come in another order among themselves (the segments they were found on differ).
        ASSERT_EQ(later_accesses(t.single), later_accesses(t.batched)) << "seed " << seed;
        auto a = formatted(t.single), b = formatted(t.batched);
        std::sort(a.begin(), a.end());
        std::sort(b.begin(), b.end());
        std::size_t first = 0;
        while (first < a.size() && first < b.size() && a[first] == b[first]) ++first;
        ASSERT_TRUE(first == a.size() && first == b.size())
            << "seed " << seed << ": " << a.size() << " vs " << b.size()
            << " hazards, first difference at " << first
            << "\n  per access: " << (first < a.size() ? a[first] : "-")
            << "\n  per command: " << (first < b.size() ? b[first] : "-");
        ASSERT_EQ(t.single.stats().accesses, t.batched.stats().accesses) << "seed " << seed;
        ASSERT_EQ(t.single.stats().duplicate_hazards, t.batched.stats().duplicate_hazards)
            << "seed " << seed;
        hazards += a.size();
    }
    EXPECT_GT(hazards, 1000u);  // the streams do collide: the comparison is not vacuous
}

TEST(SyncBatch, LongStreamsReportTheSameAcrossCommandCollections) {
    // Hundreds of commands a stream: both models drop the commands no segment names any more
    // several times (sync_model_internal.h, kCollectFloor), and still report alike.
    for (uint32_t seed = 1; seed <= 10; ++seed) {
        TwoModels t(seed);
        t.run(500, 400);
        auto a = formatted(t.single), b = formatted(t.batched);
        ASSERT_GT(a.size(), 0u) << "seed " << seed;
        ASSERT_EQ(later_accesses(t.single), later_accesses(t.batched)) << "seed " << seed;
        std::sort(a.begin(), a.end());
        std::sort(b.begin(), b.end());
        ASSERT_EQ(a, b) << "seed " << seed;
    }
}

TEST(SyncBatch, BeginsDifferingInHighBitsReportTheSame) {
    // record_accesses sorts a command's begins a digit at a time over the bits in which they
    // differ: here those span ~50 bits (seven digits), the streams above fewer than ten.
    std::size_t hazards = 0;
    for (uint32_t seed = 1; seed <= 100; ++seed) {
        TwoModels t(seed);
        t.shift = 44;
        t.run(40, 160);
        auto a = formatted(t.single), b = formatted(t.batched);
        ASSERT_EQ(later_accesses(t.single), later_accesses(t.batched)) << "seed " << seed;
        std::sort(a.begin(), a.end());
        std::sort(b.begin(), b.end());
        ASSERT_EQ(a, b) << "seed " << seed;
        hazards += a.size();
    }
    EXPECT_GT(hazards, 100u);  // the streams do collide: the comparison is not vacuous
}

TEST(SyncBatch, HazardOnAnElementRunNamesTheElement) {
    SyncModel m;
    m.begin_submission(0, 0);
    const CommandRef writer{0, 0, 1, 0, "writer"}, reader{0, 0, 1, 1, "reader"};
    std::vector<std::string> names;
    std::vector<Access> writes;
    for (int i = 0; i < 8; ++i) names.push_back("dstAddressesArray[" + std::to_string(i) + "]");
    for (int i = 0; i < 8; ++i)
        writes.push_back({{0x1000 + 8u * i, 0x1008 + 8u * i},
                          VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                          VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                          true,
                          names[std::size_t(i)]});
    m.record_accesses(writer, writes);
    // Reads bytes 4..11 of element 5 and 6's first half: two hazards, one per element.
    m.record_access(reader, {{0x102c, 0x1034},
                             VK_PIPELINE_STAGE_2_COPY_BIT,
                             VK_ACCESS_2_TRANSFER_READ_BIT,
                             false,
                             "src"});
    m.end_submission();
    ASSERT_EQ(m.hazards().size(), 2u);
    EXPECT_EQ(m.hazards()[0].prior.field, "dstAddressesArray[5]");
    EXPECT_EQ(m.hazards()[0].prior.range, (AddressRange{0x1028, 0x1030}));
    EXPECT_EQ(m.hazards()[0].overlap, (AddressRange{0x102c, 0x1030}));
    EXPECT_EQ(m.hazards()[1].prior.field, "dstAddressesArray[6]");
    EXPECT_EQ(m.hazards()[1].overlap, (AddressRange{0x1030, 0x1034}));
    EXPECT_EQ(m.stats().accesses, 9u);
}

}  // namespace
}  // namespace clastrace::replay
