// SPDX-License-Identifier: Apache-2.0
// What a replay holds must follow what is live in the trace (buffers bound, command buffers
// recorded, accesses in flight), not how long the trace is.
#include "laid_index.h"
#include "replay_bench_trace.h"
#include "replay_memory.h"

#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>
#include <clastrace/traces/trace_writer.h>

#include <gtest/gtest.h>

#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <map>
#include <random>
#include <string>
#include <tuple>
#include <vector>

namespace clastrace::replay {
namespace {

constexpr uint64_t kPage = engine::RegionBytes::kPageBytes;

std::string temp_path(const std::string& name) {
    return (testing::TempDir().empty() ? std::string("/tmp/") : testing::TempDir()) +
           "replay_memory_" + std::to_string(getpid()) + "_" + name;
}

ReplayReport replay_file(const std::string& path, const ReplayOptions& options = {}) {
    traces::TraceError error;
    auto reader = traces::TraceReader::open(path, &error);
    EXPECT_TRUE(reader) << error.message;
    if (!reader) return {};
    return replay_trace(*reader, path, options);
}

std::string describe(const ReplayReport& r) {
    std::string s;
    for (const auto& f : r.findings) s += f.format() + "\n";
    for (const auto& h : r.hazards) s += h.format() + "\n";
    return s;
}

TEST(ReplayMemory, DestroyedBufferGivesItsRegionAndPagesBack) {
    detail::ReplayMemory m;
    m.create_buffer(1, 1ull << 30, 0);
    m.bind_buffer(1, 0x10, 0, 0x100000000ull);
    const std::vector<uint8_t> bytes(3 * kPage, 0x5A);
    ASSERT_TRUE(m.write(0x100000000ull + 12345, bytes));
    EXPECT_EQ(m.image().reserved_bytes(), 1ull << 30);
    EXPECT_EQ(m.image().resident_bytes(), 4 * kPage);  // 3 pages starting mid-page
    const auto range = m.destroy_buffer(1);
    ASSERT_TRUE(range);
    EXPECT_EQ(range->begin, 0x100000000ull);
    EXPECT_EQ(range->end, 0x100000000ull + (1ull << 30));
    EXPECT_EQ(m.image().reserved_bytes(), 0u);
    EXPECT_EQ(m.image().resident_bytes(), 0u);
    EXPECT_FALSE(m.buffer_range(1, 0, 16));
    EXPECT_FALSE(m.write(0x100000000ull, bytes));  // no memory there any more
    EXPECT_FALSE(m.destroy_buffer(1));
}

// Marking engine objects over the objects of an earlier build (shifted, split, covered, met at
// one end), with plain writes cutting them now and then, keeps exactly the bytes a per-byte
// reference says the engine wrote: each snapshot laid in afterwards changes every other byte
// and none of those.
TEST(ReplayMemory, MarkedEngineObjectsMatchAPerByteReference) {
    constexpr uint64_t kBase = 0x100000000ull, kSpan = 4096;
    detail::ReplayMemory m;
    m.create_buffer(1, kSpan, 0);
    m.bind_buffer(1, 0x10, 0, kBase);
    ASSERT_TRUE(m.write(kBase, std::vector<uint8_t>(kSpan, 0xEE)));
    std::vector<bool> engine_byte(kSpan, false);
    std::vector<uint8_t> expected(kSpan, 0xEE);
    uint64_t seed = 12345;
    auto next = [&](uint64_t bound) {
        seed = seed * 6364136223846793005ull + 1442695040888963407ull;
        return (seed >> 33) % bound;
    };
    for (int round = 0; round < 400; ++round) {
        const uint64_t begin = next(kSpan - 1), size = 1 + next(round % 3 == 0 ? 600 : 90);
        const uint64_t end = std::min(kSpan, begin + size);
        m.mark_engine_object({kBase + begin, kBase + end});
        for (uint64_t b = begin; b < end; ++b) engine_byte[b] = true;
        if (round % 7 == 6) {  // a plain write ends the engine's ownership of what it covers
            const uint64_t at = next(kSpan - 1), n = std::min(kSpan - at, 1 + next(200));
            const uint8_t value = uint8_t(0xA0 + round % 16);
            ASSERT_TRUE(m.write(kBase + at, std::vector<uint8_t>(n, value)));
            for (uint64_t b = at; b < at + n; ++b) {
                engine_byte[b] = false;
                expected[b] = value;
            }
        }
        if (round % 25 != 24) continue;
        const uint8_t value = uint8_t(round / 25);
        ASSERT_TRUE(m.lay_in(kBase, std::vector<uint8_t>(kSpan, value)));
        for (uint64_t b = 0; b < kSpan; ++b)
            if (!engine_byte[b]) expected[b] = value;
        std::vector<uint8_t> now;
        ASSERT_TRUE(m.read(kBase, kSpan, &now));
        for (uint64_t b = 0; b < kSpan; ++b)
            ASSERT_EQ(now[b], expected[b]) << "round " << round << " byte " << b;
    }
}

// A content laid in again where it lies already is skipped; every way the image's bytes can
// change in between (an engine write through image(), a copy, a zero fill, the buffer destroyed
// and bound again, writes in more streams than forget_written keeps open) lays it in again.
TEST(ReplayMemory, ContentLaidInAgainAfterAnyWriteIsLaidInAgain) {
    constexpr uint64_t kBase = 0x100000000ull, kSpan = 64 * 1024, kHash = 0x1234;
    detail::ReplayMemory m;
    m.create_buffer(1, kSpan, 0);
    m.bind_buffer(1, 0x10, 0, kBase);
    std::vector<uint8_t> content(kSpan);
    for (uint64_t b = 0; b < kSpan; ++b) content[b] = uint8_t(b * 7 + 3);
    auto lies_there = [&] {
        std::vector<uint8_t> now;
        return m.read(kBase, kSpan, &now) && now == content;
    };
    ASSERT_TRUE(m.lay_in(kBase, content, kHash));
    ASSERT_TRUE(lies_there());
    ASSERT_TRUE(m.lay_in(kBase, content, kHash));  // nothing met it: skipped, still there
    ASSERT_TRUE(lies_there());

    m.image().write<uint64_t>(kBase + 4096, ~0ull, {"engine", 0});
    ASSERT_FALSE(lies_there());
    ASSERT_TRUE(m.lay_in(kBase, content, kHash));
    EXPECT_TRUE(lies_there()) << "after an engine write";

    ASSERT_TRUE(m.write(kBase + 100, std::vector<uint8_t>(10, 0)));
    ASSERT_TRUE(m.lay_in(kBase, content, kHash));
    EXPECT_TRUE(lies_there()) << "after a copy";

    ASSERT_TRUE(m.fill(kBase + 8192, 4096, 0));
    ASSERT_TRUE(m.lay_in(kBase, content, kHash));
    EXPECT_TRUE(lies_there()) << "after a zero fill";

    ASSERT_TRUE(m.destroy_buffer(1));
    m.create_buffer(2, kSpan, 0);
    m.bind_buffer(2, 0x10, 0, kBase);
    ASSERT_TRUE(m.lay_in(kBase, content, kHash));
    EXPECT_TRUE(lies_there()) << "after the buffer was destroyed and another bound there";

    // Eight interleaved rising streams through one hold of the image, as engine::execute writes.
    engine::MemoryImage& image = m.image();
    for (uint64_t k = 0; k < 64; ++k)
        image.write<uint8_t>(kBase + (k % 8) * 8192 + (k / 8) * 300, 0xEE, {"engine", 0});
    ASSERT_TRUE(m.lay_in(kBase, content, kHash));
    EXPECT_TRUE(lies_there()) << "after writes in eight streams";

    // Known without its bytes while nothing met it; not over a driver BVH's mark.
    uint64_t size = 0;
    EXPECT_TRUE(m.holds_laid_content(kBase, kHash, &size));
    EXPECT_EQ(size, kSpan);
    EXPECT_FALSE(m.holds_laid_content(kBase, kHash + 1, &size));
    EXPECT_FALSE(m.holds_laid_content(kBase + 1, kHash, &size));
    m.mark_driver_bvh({kBase + kSpan - 8, kBase + kSpan});
    EXPECT_FALSE(m.holds_laid_content(kBase, kHash, &size));
    m.image().write<uint8_t>(kBase + kSpan - 1, 0xEE, {"engine", 0});
    ASSERT_TRUE(m.fill(kBase + kSpan - 8, 8, 0));  // a plain write ends the mark
    EXPECT_FALSE(m.holds_laid_content(kBase, kHash, &size));
    ASSERT_TRUE(m.lay_in(kBase, content, kHash));
    EXPECT_TRUE(lies_there()) << "after a driver BVH's mark";
    EXPECT_TRUE(m.holds_laid_content(kBase, kHash, &size));

    // Another content at the same place, and the first one back.
    std::vector<uint8_t> other(kSpan, 0x42);
    ASSERT_TRUE(m.lay_in(kBase, other, kHash + 1));
    ASSERT_TRUE(m.lay_in(kBase, content, kHash));
    EXPECT_TRUE(lies_there()) << "after another content laid over it";
    // A content laid in over part of it.
    ASSERT_TRUE(m.lay_in(kBase + 16, std::vector<uint8_t>(16, 0x42), kHash + 2));
    ASSERT_TRUE(m.lay_in(kBase, content, kHash));
    EXPECT_TRUE(lies_there()) << "after a smaller content laid inside it";
}

// The laid contents' index against a std::map: addresses on few pages' multiples collide
// in the table, erasures shift runs that wrap past its end, and it grows under them.
TEST(ReplayMemory, LaidIndexAnswersAsAMapDoes) {
    detail::LaidIndex index;
    std::map<uint64_t, std::pair<uint64_t, uint64_t>> reference;  // begin -> (end, hash)
    std::mt19937_64 random(23);
    auto address = [&] { return 0x10000ull * (random() % 3000) + (random() % 4 == 0 ? 8 : 0); };
    for (int step = 0; step < 200000; ++step) {
        const uint64_t begin = address();
        switch (random() % 4) {
        case 0:
        case 1: {
            const uint64_t end = begin + 1 + random() % 4096, hash = random();
            index.insert(begin, end, hash);
            reference[begin] = {end, hash};
            break;
        }
        case 2:
            index.erase(begin);
            reference.erase(begin);
            break;
        default: {
            const detail::LaidIndex::Entry* found = index.find(begin);
            const auto it = reference.find(begin);
            ASSERT_EQ(found != nullptr, it != reference.end()) << "step " << step;
            if (found) {
                ASSERT_EQ(found->end, it->second.first);
                ASSERT_EQ(found->hash, it->second.second);
            }
        }
        }
        ASSERT_EQ(index.size(), reference.size());
    }
    for (const auto& [begin, content] : reference) {
        const detail::LaidIndex::Entry* found = index.find(begin);
        ASSERT_NE(found, nullptr);
        EXPECT_EQ(found->end, content.first);
    }
}

TEST(ReplayMemory, AliasedRegionStaysWhileAnotherBufferUsesIt) {
    detail::ReplayMemory m;
    m.create_buffer(1, 0x10000, 0);
    m.create_buffer(2, 0x1000, 0);
    m.bind_buffer(1, 0x10, 0, 0x200000);
    m.bind_buffer(2, 0x10, 0x1000, 0x201000);  // inside buffer 1: served by its region
    EXPECT_EQ(m.aliased_buffers(), 1u);
    ASSERT_TRUE(m.write(0x201000, std::vector<uint8_t>(16, 7)));
    m.destroy_buffer(1);  // buffer 2 still sees the bytes
    std::vector<uint8_t> out;
    ASSERT_TRUE(m.read(0x201000, 16, &out));
    EXPECT_EQ(out[15], 7);
    m.destroy_buffer(2);  // the last user of the region: it goes
    EXPECT_EQ(m.image().find_region(0x200000), nullptr);
    EXPECT_EQ(m.image().reserved_bytes(), 0u);
}

TEST(ReplayMemory, ClearingAHugeBufferCostsNoPages) {
    detail::ReplayMemory m;
    m.create_buffer(1, 4ull << 30, 0);
    m.bind_buffer(1, 0x10, 0, 0x100000000ull);
    ASSERT_TRUE(m.fill(0x100000000ull, 4ull << 30, 0));
    EXPECT_EQ(m.image().resident_bytes(), 0u);
    ASSERT_TRUE(m.fill(0x100000000ull + 8 * kPage, 2 * kPage, 0x01010101u));
    EXPECT_EQ(m.image().resident_bytes(), 2 * kPage);
    std::vector<uint8_t> out;
    ASSERT_TRUE(m.read(0x100000000ull + 8 * kPage + 100, 4, &out));
    EXPECT_EQ(out[3], 1);
}

TEST(ReplayMemory, WritesPastTheBudgetAreRefusedAndCounted) {
    detail::ReplayMemory m(2 * kPage);
    m.create_buffer(1, 1ull << 30, 0);
    m.bind_buffer(1, 0x10, 0, 0x100000000ull);  // reserving far more than the budget is fine
    EXPECT_TRUE(m.over_budget().empty());
    EXPECT_TRUE(m.write(0x100000000ull, std::vector<uint8_t>(2 * kPage, 1)));
    EXPECT_FALSE(m.write(0x100000000ull + (1ull << 29), std::vector<uint8_t>(8, 1)));
    EXPECT_EQ(m.writes_over_budget(), 1u);
    EXPECT_TRUE(m.write(0x100000000ull + 100, std::vector<uint8_t>(8, 2)));  // pages already held
}

// The bench's frames: CLAS, BLAS and move builds with a streamed buffer destroyed and
// re-created at a new address every 16 frames. Four times the frames must not need more
// memory image (without freeing destroyed buffers it grows by one buffer per 16 frames).
TEST(ReplayMemory, PeakImageDoesNotGrowWithTraceLength) {
    bench::BenchTraceShape shape;
    shape.clusters_per_build = 8;
    shape.cluster_pool = 16;
    uint64_t peak[2] = {};
    uint64_t destroyed[2] = {};
    for (int i = 0; i < 2; ++i) {
        const std::string path = temp_path("frames" + std::to_string(i) + ".clt");
        shape.target_ops = i == 0 ? 2000 : 8000;
        destroyed[i] = bench::write_bench_trace(path, shape).buffers_destroyed;
        const ReplayReport r = replay_file(path);
        EXPECT_TRUE(r.clean()) << describe(r);
        EXPECT_GT(r.counts.cluster_ops, shape.target_ops / 2);
        peak[i] = r.counts.peak_image_bytes;
        std::remove(path.c_str());
    }
    EXPECT_GE(destroyed[1], 4 * destroyed[0] - 4);
    EXPECT_GT(peak[0], 0u);
    EXPECT_LE(peak[1], peak[0] + 4 * kPage)
        << "short trace " << peak[0] << " bytes, 4x longer " << peak[1];
}

// Command buffers that are never re-begun or reset (new handles every frame, not
// ONE_TIME_SUBMIT) are dropped past max_recorded_bytes; submitting one again is named.
TEST(ReplayMemory, RecordedCommandBuffersAreBoundedAndADroppedOneIsNamed) {
    const std::string path = temp_path("command_buffers.clt");
    {
        fbs::TraceHeaderT header;
        traces::TraceError error;
        traces::TraceWriterOptions o;
        o.sync_on_finish = false;
        auto w = traces::TraceWriter::create(path, header, o, &error);
        ASSERT_TRUE(w) << error.message;
        auto append = [&](auto body) {
            fbs::RecordT r;
            r.body.Set(std::move(body));
            ASSERT_FALSE(w->append(r));
        };
        fbs::BufferCreateT create;
        create.buffer = 0xb1;
        create.size = 4096;
        append(create);
        fbs::BufferBindMemoryT bind;
        bind.buffer = 0xb1;
        bind.memory = 0x1001;
        bind.device_address = 0x100000;
        append(bind);
        auto submit = [&](uint64_t cb, uint64_t fence) {
            fbs::QueueSubmitT s;
            s.queue = 0x9001;
            s.version = 2;
            auto batch = std::make_unique<fbs::SubmitBatchT>();
            batch->command_buffers.push_back(cb);
            s.batches.push_back(std::move(batch));
            s.fence = fence;
            s.submission_index = w->next_submission_index();
            append(std::move(s));
            fbs::FenceWaitT wait;
            wait.fences.push_back(fence);
            wait.wait_all = true;
            append(std::move(wait));
        };
        for (uint64_t cb = 0xc000; cb < 0xc000 + 64; ++cb) {
            fbs::CommandBufferBeginT begin;
            begin.command_buffer = cb;
            append(begin);
            for (int k = 0; k < 8; ++k) {
                fbs::CmdFillBufferT fill;
                fill.command_buffer = cb;
                fill.dst_buffer = 0xb1;
                fill.dst_offset = uint64_t(k) * 256;
                fill.size = 256;
                fill.data = uint32_t(cb);
                append(fill);
            }
            fbs::CommandBufferEndT end;
            end.command_buffer = cb;
            append(end);
            submit(cb, 0xfe0);
        }
        submit(0xc000 + 63, 0xfe0);  // the latest: still recorded
        submit(0xc000, 0xfe0);       // the oldest: dropped under a small limit
        ASSERT_FALSE(w->finish());
    }
    ReplayOptions small;
    small.max_recorded_bytes = 4096;
    ReplayReport r = replay_file(path, small);
    EXPECT_TRUE(r.findings.empty()) << describe(r);
    ASSERT_EQ(r.notes.size(), 1u) << describe(r);  // a limit of the replay: a note
    EXPECT_EQ(r.notes[0].rule, "CLASTRACE-replay-command-buffer-dropped");
    EXPECT_NE(r.notes[0].message.find("0xc000"), std::string::npos) << r.notes[0].message;
    EXPECT_EQ(r.counts.commands, 8u * 65);
    r = replay_file(path);  // the default keeps them all
    EXPECT_TRUE(r.clean()) << describe(r);
    EXPECT_EQ(r.counts.commands, 8u * 66);
    std::remove(path.c_str());
}

// A 1 GiB buffer whose trace references 1 MiB of it costs about 1 MiB in the replay.
TEST(ReplayMemory, GiBBufferWithOneMiBReferencedCostsAboutOneMiB) {
    const std::string path = temp_path("gib.clt");
    constexpr uint64_t kMiB = 1ull << 20, kBig = 0x200000000ull, kStaging = 0x300000000ull;
    {
        fbs::TraceHeaderT header;
        traces::TraceError error;
        traces::TraceWriterOptions o;
        o.sync_on_finish = false;
        auto w = traces::TraceWriter::create(path, header, o, &error);
        ASSERT_TRUE(w) << error.message;
        auto append = [&](auto body) {
            fbs::RecordT r;
            r.body.Set(std::move(body));
            ASSERT_FALSE(w->append(r));
        };
        for (const auto& [handle, address, size] :
             {std::tuple{0xb1ull, kBig, 1ull << 30}, {0xb2ull, kStaging, kMiB}}) {
            fbs::BufferCreateT create;
            create.buffer = handle;
            create.size = size;
            append(create);
            fbs::BufferBindMemoryT bind;
            bind.buffer = handle;
            bind.memory = handle + 0x1000;
            bind.device_address = address;
            append(bind);
        }
        fbs::CommandBufferBeginT begin;
        begin.command_buffer = 0xc1;
        append(begin);
        std::vector<uint8_t> bytes(kMiB);
        for (size_t i = 0; i < bytes.size(); ++i) bytes[i] = uint8_t(i * 31 + 7);
        fbs::CmdCopyBufferT copy;
        copy.command_buffer = 0xc1;
        copy.version = 1;
        copy.src_buffer = 0xb2;
        copy.dst_buffer = 0xb1;
        copy.regions.emplace_back(0, 512 * kMiB, kMiB);
        fbs::MemorySnapshot snap;
        ASSERT_FALSE(w->snapshot(0xb2, 0, kStaging, bytes.data(), bytes.size(), &snap));
        copy.inputs.push_back(snap);
        append(std::move(copy));
        fbs::CmdFillBufferT clear;  // clearing the whole GiB costs nothing either
        clear.command_buffer = 0xc1;
        clear.dst_buffer = 0xb1;
        clear.dst_offset = 600 * kMiB;
        clear.size = ~0ull;
        append(clear);
        fbs::QueueSubmitT s;
        s.queue = 0x9001;
        s.version = 2;
        auto batch = std::make_unique<fbs::SubmitBatchT>();
        batch->command_buffers.push_back(0xc1);
        s.batches.push_back(std::move(batch));
        s.submission_index = w->next_submission_index();
        append(std::move(s));
        ASSERT_FALSE(w->finish());
    }
    const ReplayReport r = replay_file(path);
    EXPECT_TRUE(r.clean()) << describe(r);
    EXPECT_EQ(r.counts.copies, 2u);
    EXPECT_GE(r.counts.peak_image_bytes, 2 * kMiB);  // the staging MiB and the copied MiB
    EXPECT_LE(r.counts.peak_image_bytes, 2 * kMiB + 4 * kPage);
    std::remove(path.c_str());
}

}  // namespace
}  // namespace clastrace::replay
