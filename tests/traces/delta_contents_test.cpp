// SPDX-License-Identifier: Apache-2.0
// Delta storage (MemoryContentsDelta, format 1.7, issue 23): contents of a snapshot range stored
// XOR the range's previous contents read back as the real bytes, through next() and
// read_contents, in scan order and out of it; old traces (whole contents only) read as before.
#include "trace_test_support.h"

#include "file_format.h"

#include <clastrace/traces/records.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <map>

namespace clastrace::traces::testing {
namespace {

// A frame loop's snapshots: three ranges whose bytes change a little every frame (one moves a
// few floats, one flips a byte, one stays), in chunks small enough that chains cross chunks.
struct DeltaTrace {
    std::map<uint64_t, std::vector<uint8_t>> bytes_by_key;  // what the writer was given
    std::vector<uint64_t> snapshot_keys;                    // in write order
    TraceWriterStats stats;
};

DeltaTrace write_delta_trace(const std::string& path, TraceWriterOptions options, int frames,
                             uint32_t chunk_bytes = 8192, size_t vertex_count = 600) {
    DeltaTrace out;
    options.chunk_raw_bytes = chunk_bytes;
    TraceError e;
    auto w = TraceWriter::create(path, test_header(), options, &e);
    EXPECT_TRUE(w) << e.message;
    if (!w) return out;
    std::vector<float> vertices(vertex_count);
    for (size_t i = 0; i < vertices.size(); ++i) vertices[i] = std::sin(0.1f * float(i));
    std::vector<uint8_t> flags(256, 0x5a), constant(100, 0x77);
    for (int f = 0; f < frames; ++f) {
        for (int k = 0; k < 6; ++k) vertices[(f * 37 + k * 11) % vertices.size()] += 0.5f;
        flags[f % flags.size()] ^= 0xff;
        const std::vector<uint64_t> keys =
            append_build_snapshotting(*w,
                                      {{1, vertices.data(), vertices.size() * 4},
                                       {2, flags.data(), flags.size()},
                                       {3, constant.data(), constant.size()}},
                                      out.bytes_by_key);
        out.snapshot_keys.insert(out.snapshot_keys.end(), keys.begin(), keys.end());
    }
    EXPECT_FALSE(w->finish());
    out.stats = w->stats();
    return out;
}

TEST(DeltaContents, RoundTripHandsOutTheRealBytesInScanOrder) {
    const std::string path = temp_path("delta_round_trip.clt");
    const DeltaTrace written = write_delta_trace(path, {}, 60);
    // Every frame's vertices and flags are new: all but the first of each range are deltas.
    EXPECT_EQ(written.stats.contents_stored, 121u);
    EXPECT_EQ(written.stats.contents_delta_stored, 118u);
    ReadResult read = read_all(path);
    ASSERT_EQ(read.damage_count, 0u) << describe(read.damage);
    size_t contents = 0, deltas = 0;
    for (const fbs::RecordT& r : read.records) {
        const auto* whole = r.body.AsMemoryContents();
        const auto* delta = r.body.AsMemoryContentsDelta();
        if (!whole && !delta) continue;
        ++contents;
        deltas += delta != nullptr;
        const uint64_t hash = whole ? whole->hash : delta->hash;
        ASSERT_TRUE(written.bytes_by_key.count(hash));
        EXPECT_EQ(whole ? whole->bytes : delta->bytes, written.bytes_by_key.at(hash))
            << "contents " << hash;
        if (delta) {
            EXPECT_EQ(delta->byte_planes, 4);  // the default layout
        }
    }
    EXPECT_EQ(contents, 121u);
    EXPECT_EQ(deltas, 118u);
}

// read_contents far from the scan (a fresh reader, newest first, from the index) walks each
// chain back to whole contents; the same reader then answers from what it resolved.
TEST(DeltaContents, ReadContentsResolvesChainsOutOfOrder) {
    const std::string path = temp_path("delta_out_of_order.clt");
    const DeltaTrace written = write_delta_trace(path, {}, 60);
    TraceError e;
    auto reader = TraceReader::open(path, &e);
    ASSERT_TRUE(reader && reader->has_index()) << e.message;
    std::vector<uint8_t> got;
    for (auto it = written.snapshot_keys.rbegin(); it != written.snapshot_keys.rend(); ++it) {
        ASSERT_FALSE(reader->read_contents(*it, &got));
        EXPECT_EQ(got, written.bytes_by_key.at(*it));
    }
    // And while scanning, every snapshot's bytes through read_contents.
    auto scan = TraceReader::open(path, &e);
    ASSERT_TRUE(scan);
    RecordView v;
    size_t checked = 0;
    while (scan->next(&v)) {
        const SnapshotLists lists = record_snapshots(*v.record);
        if (!lists.inputs) continue;
        for (const fbs::MemorySnapshot* s : *lists.inputs) {
            ASSERT_FALSE(scan->read_contents(s->hash(), &got));
            EXPECT_EQ(got, written.bytes_by_key.at(s->hash()));
            ++checked;
        }
    }
    EXPECT_EQ(checked, written.snapshot_keys.size());
    EXPECT_EQ(scan->damage_count(), 0u);
}

// Contents read back once stay with the reader (up to its read-back budget): reading every
// snapshot again after the scan passed their chunks decompresses nothing more, with the same bytes,
// copied (read_contents) or viewed (read_contents_view).
TEST(DeltaContents, ContentsReadAgainAreNotDecompressedAgain) {
    const std::string path = temp_path("delta_read_again.clt");
    const DeltaTrace written = write_delta_trace(path, {}, 60);
    TraceError e;
    auto reader = TraceReader::open(path, &e, {.verify_content_keys = true});
    ASSERT_TRUE(reader) << e.message;
    RecordView v;
    while (reader->next(&v)) {}
    ASSERT_GT(reader->stats().chunks_read, 10u);  // the scan passed the chunks read below
    std::vector<uint8_t> got;
    uint64_t decompressed_after_first = 0;
    for (int reading = 0; reading < 2; ++reading) {
        for (uint64_t key : written.snapshot_keys) {
            ASSERT_FALSE(reader->read_contents(key, &got));
            EXPECT_EQ(got, written.bytes_by_key.at(key));
            std::span<const uint8_t> view;
            ASSERT_FALSE(reader->read_contents_view(key, &view));
            EXPECT_TRUE(std::ranges::equal(view, written.bytes_by_key.at(key)));
        }
        if (reading == 0) decompressed_after_first = reader->stats().raw_bytes_decompressed;
    }
    EXPECT_EQ(reader->stats().raw_bytes_decompressed, decompressed_after_first);
    EXPECT_EQ(reader->damage_count(), 0u);
}

// Chunks big enough to be read ahead (256 KiB and more) have their deltas XORed on the read-ahead
// task: every one of them here, with the same records and bytes as decoding on the caller's
// thread (TraceReaderOptions::decode_deltas_ahead = false).
TEST(DeltaContents, DeltasOfChunksReadAheadAreDecodedOnTheReadAheadTask) {
    const std::string path = temp_path("delta_read_ahead.clt");
    const DeltaTrace written = write_delta_trace(path, {}, 40, 1u << 20, 100'000);
    ASSERT_EQ(written.stats.contents_delta_stored, 78u);
    TraceReaderOptions ahead{.verify_content_keys = true};
    TraceReaderOptions here = ahead;
    here.decode_deltas_ahead = false;
    const ReadResult on = read_all(path, ahead);
    const ReadResult off = read_all(path, here);
    ASSERT_EQ(on.damage_count, 0u) << describe(on.damage);
    ASSERT_EQ(off.damage_count, 0u) << describe(off.damage);
    EXPECT_GT(on.stats.chunks_read, 4u);
    EXPECT_EQ(on.stats.deltas_decoded_ahead, 78u);
    EXPECT_EQ(off.stats.deltas_decoded_ahead, 0u);
    ASSERT_EQ(on.records.size(), off.records.size());
    size_t deltas = 0;
    for (size_t i = 0; i < on.records.size(); ++i) {
        const auto* delta = on.records[i].body.AsMemoryContentsDelta();
        if (!delta) continue;
        ++deltas;
        EXPECT_EQ(delta->bytes, written.bytes_by_key.at(delta->hash));
        ASSERT_TRUE(off.records[i].body.AsMemoryContentsDelta());
        EXPECT_EQ(off.records[i].body.AsMemoryContentsDelta()->bytes, delta->bytes);
    }
    EXPECT_EQ(deltas, 78u);
}

// A range's first delta finds its base (stored whole, before the trace showed any delta) in a
// chunk the reader still holds, the one being read or the one before it, instead of
// decompressing that chunk again: every records chunk is decompressed once, whether frames fit
// in a chunk or each vertex content fills one of its own (its base then two chunks back).
TEST(DeltaContents, FirstDeltasDoNotDecompressTheirBasesChunkAgain) {
    for (size_t vertex_count : {size_t{100'000}, size_t{300'000}}) {
        SCOPED_TRACE(vertex_count);
        const std::string path = temp_path("delta_first_bases.clt");
        const DeltaTrace written = write_delta_trace(path, {}, 12, 1u << 20, vertex_count);
        ASSERT_EQ(written.stats.contents_delta_stored, 22u);
        const ReadResult read = read_all(path);
        ASSERT_EQ(read.damage_count, 0u) << describe(read.damage);
        EXPECT_EQ(read.stats.deltas_decoded_ahead, 22u);
        // Besides the records chunks, only the index (a few kB) is decompressed.
        EXPECT_GE(read.stats.raw_bytes_decompressed, read.stats.raw_bytes);
        EXPECT_LT(read.stats.raw_bytes_decompressed, read.stats.raw_bytes + (64u << 10));
    }
}

// A base a delta used goes to a small budget of its own, so the buffers of a frame loop's
// contents are filled again within a few frames: 40 frames of a 1 MB range take far fewer than
// 40 MB of fresh buffers (all 40 while the reader kept every base until 64 MiB).
TEST(DeltaContents, UsedBasesComeBackToBeFilledAgain) {
    const std::string path = temp_path("delta_used_bases.clt");
    const DeltaTrace written = write_delta_trace(path, {}, 40, 1u << 20, 250'000);
    ASSERT_EQ(written.stats.contents_delta_stored, 78u);
    for (bool ahead : {true, false}) {
        TraceReaderOptions options;
        options.decode_deltas_ahead = ahead;
        const ReadResult read = read_all(path, options);
        ASSERT_EQ(read.damage_count, 0u) << describe(read.damage);
        for (const fbs::RecordT& r : read.records) {
            if (const auto* delta = r.body.AsMemoryContentsDelta()) {
                ASSERT_EQ(delta->bytes, written.bytes_by_key.at(delta->hash));
            }
        }
        // 16 MiB of used bases, the newest bases and those in flight between the two threads.
        EXPECT_LT(read.stats.real_bytes_allocated, 24'000'000u) << "read ahead " << ahead;
        EXPECT_GT(read.stats.real_bytes_allocated, 1'000'000u) << "read ahead " << ahead;
    }
}

// The chain limit stores contents whole again after that many deltas, and the writer forgets
// ranges past its byte budget (their next contents go whole): both still read back exactly.
TEST(DeltaContents, ChainLimitAndBaseBudgetStoreWholeContentsAgain) {
    TraceWriterOptions limited;
    limited.delta_chain_limit = 4;
    const DeltaTrace chains = write_delta_trace(temp_path("delta_chain4.clt"), limited, 60);
    // Two changing ranges of 60 contents each: a whole one, then 4 deltas, again and again.
    EXPECT_EQ(chains.stats.contents_delta_stored, 2u * 48u);
    TraceWriterOptions small;
    small.delta_base_bytes = 1024;  // the vertices (2400 bytes) are over a quarter of it
    const DeltaTrace budget = write_delta_trace(temp_path("delta_budget.clt"), small, 60);
    EXPECT_EQ(budget.stats.contents_delta_stored, 59u);  // the flags only
    for (const char* name : {"delta_chain4.clt", "delta_budget.clt"}) {
        ReadResult read = read_all(temp_path(name));
        EXPECT_EQ(read.damage_count, 0u) << name << ": " << describe(read.damage);
        const DeltaTrace& w = std::string(name) == "delta_chain4.clt" ? chains : budget;
        for (const fbs::RecordT& r : read.records) {
            if (const auto* c = r.body.AsMemoryContents()) {
                EXPECT_EQ(c->bytes, w.bytes_by_key.at(c->hash)) << name;
            }
            if (const auto* c = r.body.AsMemoryContentsDelta()) {
                EXPECT_EQ(c->bytes, w.bytes_by_key.at(c->hash)) << name;
            }
        }
    }
}

TEST(DeltaContents, DeltasMakeTheFileSmallerThanWholeContents) {
    TraceWriterOptions whole;
    whole.delta_contents = false;
    write_delta_trace(temp_path("delta_off.clt"), whole, 60);
    const DeltaTrace on = write_delta_trace(temp_path("delta_on.clt"), {}, 60);
    EXPECT_EQ(on.stats.contents_delta_stored, 118u);
    const auto off_size = std::filesystem::file_size(temp_path("delta_off.clt"));
    const auto on_size = std::filesystem::file_size(temp_path("delta_on.clt"));
    EXPECT_LT(on_size * 2, off_size) << on_size << " vs " << off_size;
}

// The committed traces of format 1.0-1.5 hold whole contents only: every record reads with its
// bytes hashing to its key, and read_contents gives the record's own bytes.
TEST(DeltaContents, OldSampleTracesReadTheirContentsUnchanged) {
    const std::filesystem::path samples = std::filesystem::path(CLASTRACE_SAMPLE).parent_path();
    size_t traces = 0;
    for (const auto& entry : std::filesystem::directory_iterator(samples)) {
        if (entry.path().extension() != ".clt") continue;
        ++traces;
        SCOPED_TRACE(entry.path().string());
        TraceError e;
        TraceReaderOptions verify;
        verify.verify_content_keys = true;
        auto reader = TraceReader::open(entry.path().string(), &e, verify);
        ASSERT_TRUE(reader) << e.message;
        std::vector<std::pair<uint64_t, std::vector<uint8_t>>> seen;
        RecordView v;
        while (reader->next(&v))
            if (const auto* c = v.record->body_as_MemoryContents()) {
                seen.emplace_back(c->hash(),
                                  std::vector<uint8_t>(c->bytes()->begin(), c->bytes()->end()));
            }
        EXPECT_EQ(reader->damage_count(), 0u);
        EXPECT_FALSE(seen.empty());
        std::vector<uint8_t> got;
        for (const auto& [hash, bytes] : seen) {
            ASSERT_FALSE(reader->read_contents(hash, &got));
            EXPECT_EQ(got, bytes);
            EXPECT_EQ(format::content_key(got.data(), got.size(), 0, 64), hash);
        }
    }
    EXPECT_GE(traces, 4u);
}

}  // namespace
}  // namespace clastrace::traces::testing
