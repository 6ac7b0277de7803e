// SPDX-License-Identifier: Apache-2.0
// Writing then reading gives back exactly what was written: every record kind, the
// header, memory contents (stored once), and seeking by submission.
#include "trace_test_support.h"

#include <clastrace/traces/records.h>

#include <gtest/gtest.h>

#include <csignal>
#include <random>
#include <set>
#include <sys/resource.h>

namespace clastrace::traces::testing {
namespace {

bool contents_record_kind(fbs::RecordBody kind) {
    return kind == fbs::RecordBody::MemoryContents || kind == fbs::RecordBody::MemoryContentsDelta;
}

std::vector<fbs::RecordT> without_contents(const std::vector<fbs::RecordT>& records) {
    std::vector<fbs::RecordT> out;
    for (const fbs::RecordT& r : records)
        if (!contents_record_kind(r.body.type)) out.push_back(r);
    return out;
}

TEST(TraceRoundTrip, EveryRecordKindComesBackEqual) {
    const std::string path = temp_path("every_kind.clt");
    TraceError e;
    TraceWriterOptions options;
    options.chunk_raw_bytes = 4096;  // several chunks
    auto w = TraceWriter::create(path, test_header(), options, &e);
    ASSERT_TRUE(w) << e.message;
    std::vector<fbs::RecordT> written = one_of_every_kind(*w);
    for (const fbs::RecordT& r : written)
        ASSERT_FALSE(w->append(r)) << record_kind_name(r.body.type);
    ASSERT_FALSE(w->finish());

    // The list covers every kind the schema has (MemoryContents comes from add_contents,
    // MemoryContentsDelta from snapshot(): DeltaContents.* covers it).
    std::set<fbs::RecordBody> kinds;
    for (const fbs::RecordT& r : written) kinds.insert(r.body.type);
    kinds.insert(fbs::RecordBody::MemoryContents);
    kinds.insert(fbs::RecordBody::MemoryContentsDelta);
    EXPECT_EQ(kinds.size(), kRecordKindCount - 1)
        << "a record kind was added without a round-trip case";

    ReadResult read = read_all(path);
    ASSERT_TRUE(read.opened) << read.open_error.message;
    EXPECT_EQ(read.damage_count, 0u) << describe(read.damage);
    EXPECT_TRUE(read.has_index);
    std::vector<fbs::RecordT> back = without_contents(read.records);
    ASSERT_EQ(back.size(), written.size());
    for (size_t i = 0; i < written.size(); ++i) {
        EXPECT_TRUE(back[i] == written[i])
            << "record " << i << " (" << record_kind_name(written[i].body.type)
            << ") differs after the round trip";
    }
}

TEST(TraceRoundTrip, HeaderComesBackWithWriterSettings) {
    const std::string path = temp_path("header.clt");
    TraceError e;
    TraceWriterOptions options;
    options.zstd_level = 7;
    options.chunk_raw_bytes = 65536;
    auto w = TraceWriter::create(path, test_header(), options, &e);
    ASSERT_TRUE(w);
    ASSERT_FALSE(w->finish());
    auto reader = TraceReader::open(path, &e);
    ASSERT_TRUE(reader) << e.message;
    ASSERT_NE(reader->header(), nullptr);
    fbs::TraceHeaderT h;
    reader->header()->UnPackTo(&h);
    fbs::TraceHeaderT expected = test_header();
    expected.capture->zstd_level = 7;
    expected.capture->chunk_raw_bytes = 65536;
    expected.capture->content_hash_bits = 64;
    EXPECT_TRUE(h == expected);
    EXPECT_EQ(reader->version_major(), 1);
    RecordView v;
    EXPECT_FALSE(reader->next(&v));  // no records
    EXPECT_EQ(reader->damage_count(), 0u) << describe(reader->damage());
}

TEST(TraceRoundTrip, IdenticalSnapshotsAreStoredOnce) {
    const std::string path = temp_path("dedup.clt");
    TraceError e;
    auto w = TraceWriter::create(path, test_header(), {}, &e);
    ASSERT_TRUE(w);
    std::vector<uint8_t> bytes(10000);
    for (size_t i = 0; i < bytes.size(); ++i) bytes[i] = static_cast<uint8_t>(i * 31 + 5);
    std::vector<uint8_t> copy = bytes;  // equal bytes at another address
    fbs::MemorySnapshot s1, s2, s3;
    ASSERT_FALSE(w->snapshot(1, 0, 0x1000, bytes.data(), bytes.size(), &s1));
    ASSERT_FALSE(w->snapshot(2, 0, 0x9000, copy.data(), copy.size(), &s2));
    copy[5000] ^= 1;
    ASSERT_FALSE(w->snapshot(2, 0, 0x9000, copy.data(), copy.size(), &s3));
    EXPECT_EQ(s1.hash(), s2.hash());
    EXPECT_NE(s1.hash(), s3.hash());
    fbs::CmdCopyBufferT cmd;
    cmd.inputs = {s1, s3};
    cmd.outputs = {s2};
    fbs::RecordT r;
    r.body.Set(std::move(cmd));
    ASSERT_FALSE(w->append(r));
    TraceWriterStats st = w->stats();
    EXPECT_EQ(st.contents_stored, 2u);
    EXPECT_EQ(st.contents_deduplicated, 1u);
    EXPECT_EQ(st.contents_bytes_stored, 20000u);
    ASSERT_FALSE(w->finish());

    ReadResult read = read_all(path);
    ASSERT_TRUE(read.opened);
    EXPECT_EQ(read.damage_count, 0u) << describe(read.damage);
    int contents = 0;
    for (const fbs::RecordT& rec : read.records) contents += contents_record_kind(rec.body.type);
    EXPECT_EQ(contents, 2);

    auto reader = TraceReader::open(path, &e);
    ASSERT_TRUE(reader);
    std::vector<uint8_t> got;
    ASSERT_FALSE(reader->read_contents(s1.hash(), &got));
    EXPECT_EQ(got, bytes);
    ASSERT_FALSE(reader->read_contents(s3.hash(), &got));
    EXPECT_EQ(got, copy);
    EXPECT_EQ(reader->read_contents(0x1234, &got).code, TraceErrorCode::kMissingContents);
}

TEST(TraceRoundTrip, HashCollisionsGetDistinctKeysAndTheRightBytes) {
    // 8-bit keys: 200 distinct byte strings must collide many times.
    const std::string path = temp_path("collide.clt");
    TraceError e;
    TraceWriterOptions options;
    options.content_hash_bits = 8;
    options.chunk_raw_bytes = 4096;
    auto w = TraceWriter::create(path, test_header(), options, &e);
    ASSERT_TRUE(w) << e.message;
    std::vector<std::vector<uint8_t>> blobs;
    std::vector<uint64_t> keys;
    for (int i = 0; i < 200; ++i) {
        std::vector<uint8_t> b(16 + i % 7, static_cast<uint8_t>(i));
        b[0] = static_cast<uint8_t>(i >> 8);
        uint64_t key = 0;
        ASSERT_FALSE(w->add_contents(b.data(), b.size(), &key));
        EXPECT_LT(key, 256u);
        blobs.push_back(b);
        keys.push_back(key);
    }
    // Asking again for the same bytes gives the same keys (seed search is deterministic).
    for (int i = 0; i < 200; ++i) {
        uint64_t key = 0;
        ASSERT_FALSE(w->add_contents(blobs[i].data(), blobs[i].size(), &key));
        EXPECT_EQ(key, keys[i]);
    }
    EXPECT_EQ(std::set<uint64_t>(keys.begin(), keys.end()).size(), 200u);
    EXPECT_GT(w->stats().hash_collisions, 0u);
    ASSERT_FALSE(w->finish());

    auto reader = TraceReader::open(path, &e);
    ASSERT_TRUE(reader) << e.message;
    RecordView v;
    while (reader->next(&v)) {}
    EXPECT_EQ(reader->damage_count(), 0u) << describe(reader->damage());
    std::vector<uint8_t> got;
    for (int i = 0; i < 200; ++i) {
        ASSERT_FALSE(reader->read_contents(keys[i], &got));
        EXPECT_EQ(got, blobs[i]) << i;
    }
}

TEST(TraceRoundTrip, ManyChunksAndSeekToEverySubmission) {
    const std::string path = temp_path("frames.clt");
    std::vector<fbs::RecordT> written = write_frames_trace(path, 40, 8192);
    ReadResult read = read_all(path);
    ASSERT_TRUE(read.opened);
    EXPECT_EQ(read.damage_count, 0u) << describe(read.damage);
    std::vector<fbs::RecordT> back = without_contents(read.records);
    ASSERT_EQ(back.size(), written.size());
    for (size_t i = 0; i < written.size(); ++i) EXPECT_TRUE(back[i] == written[i]) << i;

    TraceError e;
    auto reader = TraceReader::open(path, &e);
    ASSERT_TRUE(reader);
    ASSERT_TRUE(reader->has_index());
    EXPECT_EQ(reader->indexed_submission_count(), 40u);
    for (uint64_t k : {39u, 0u, 17u, 18u, 5u}) {
        ASSERT_FALSE(reader->seek_to_submission(k)) << k;
        RecordView v;
        ASSERT_TRUE(reader->next(&v));
        ASSERT_EQ(v.kind, fbs::RecordBody::QueueSubmit);
        EXPECT_EQ(v.record->body_as_QueueSubmit()->submission_index(), k);
        // The submission after it follows, its build's snapshots resolve via the index.
        if (k + 1 < 40) {
            ASSERT_TRUE(reader->next(&v));
            EXPECT_EQ(v.kind, fbs::RecordBody::CommandBufferBegin);
            do {
                ASSERT_TRUE(reader->next(&v));
            } while (contents_record_kind(v.kind));
            ASSERT_EQ(v.kind, fbs::RecordBody::CmdBuildClusterAccelerationStructureIndirect);
            std::vector<uint8_t> bytes;
            const auto* in =
                v.record->body_as_CmdBuildClusterAccelerationStructureIndirect()->inputs();
            ASSERT_FALSE(reader->read_contents(in->Get(0)->hash(), &bytes));
            EXPECT_EQ(bytes.size(), 3u * 256u * 4u);
        }
    }
    EXPECT_EQ(reader->seek_to_submission(40).code, TraceErrorCode::kInvalidArgument);
    EXPECT_EQ(reader->damage_count(), 0u) << describe(reader->damage());
}

// Several compression threads compress chunks side by side and write them in their order: the
// file is the one a single thread writes, byte for byte.
TEST(TraceRoundTrip, CompressionThreadsWriteTheFileOneThreadWrites) {
    const std::string one_path = temp_path("one_compressor.clt");
    const std::string three_path = temp_path("three_compressors.clt");
    write_frames_trace(one_path, 60, 4096);
    TraceWriterOptions three;
    three.compressor_threads = 3;
    three.max_chunks_in_flight = 1;
    const std::vector<fbs::RecordT> written = write_frames_trace(three_path, 60, 4096, three);
    const std::vector<uint8_t> one = read_file(one_path);
    EXPECT_GT(one.size(), 20u * 1024u);  // many chunks
    EXPECT_TRUE(read_file(three_path) == one);
    ReadResult read = read_all(three_path);
    EXPECT_EQ(read.damage_count, 0u) << describe(read.damage);
    EXPECT_EQ(without_contents(read.records).size(), written.size());
}

TEST(TraceRoundTrip, SeekWorksWithoutIndexByScanning) {
    const std::string path = temp_path("noindex.clt");
    write_frames_trace(path, 10, 8192);
    std::vector<uint8_t> bytes = read_file(path);
    bytes.resize(bytes.size() - 32);  // drop the trailer: the index can no longer be found
    TraceError e;
    auto reader = TraceReader::open_memory(bytes.data(), bytes.size(), "noindex.clt", &e);
    ASSERT_TRUE(reader);
    EXPECT_FALSE(reader->has_index());
    ASSERT_FALSE(reader->seek_to_submission(7));
    RecordView v;
    ASSERT_TRUE(reader->next(&v));
    EXPECT_EQ(v.record->body_as_QueueSubmit()->submission_index(), 7u);
}

// The reader's chunk buffers grow to the largest chunk, not to twice the one before it:
// vector::resize doubles, and four such buffers were replay's peak memory. Chunks of one
// incompressible content each, every one 10 kB larger than the last, all read ahead.
TEST(TraceReaderMemory, ChunkBuffersGrowToTheLargestChunkNotTwiceIt) {
    const std::string path = temp_path("growing_chunks.clt");
    TraceWriterOptions options;
    options.chunk_raw_bytes = 64u << 10;  // each content seals a chunk of its own
    TraceError e;
    auto w = TraceWriter::create(path, test_header(), options, &e);
    ASSERT_TRUE(w) << e.message;
    std::mt19937 rng(3);
    constexpr size_t kLargest = 300'000 + 10'000 * 7;
    for (size_t size = 300'000; size <= kLargest; size += 10'000) {
        std::vector<uint8_t> bytes(size);
        for (uint8_t& b : bytes) b = static_cast<uint8_t>(rng());
        uint64_t key = 0;
        ASSERT_FALSE(w->add_contents(bytes.data(), bytes.size(), &key));
    }
    ASSERT_FALSE(w->finish());
    auto reader = TraceReader::open(path, &e);
    ASSERT_TRUE(reader) << e.message;
    RecordView v;
    while (reader->next(&v)) {}
    ASSERT_EQ(reader->damage_count(), 0u);
    EXPECT_EQ(reader->stats().chunks_read, 8u);
    // Decompressed and compressed bytes of the chunk read and of the one read ahead: each at
    // most the largest chunk (its frame and zstd's block headers add a few hundred bytes).
    const uint64_t largest_chunk = kLargest + 1024;
    EXPECT_LE(reader->stats().chunk_buffer_bytes, 4 * largest_chunk);
    EXPECT_GE(reader->stats().chunk_buffer_bytes, 2 * kLargest);
}

TEST(TraceWriterRules, RejectsMisuse) {
    const std::string path = temp_path("misuse.clt");
    TraceError e;
    TraceWriterOptions bad;
    bad.chunk_raw_bytes = 10;
    EXPECT_FALSE(TraceWriter::create(path, test_header(), bad, &e));
    EXPECT_EQ(e.code, TraceErrorCode::kInvalidArgument);
    TraceWriterOptions no_compressor;
    no_compressor.compressor_threads = 0;
    EXPECT_FALSE(TraceWriter::create(path, test_header(), no_compressor, &e));
    EXPECT_EQ(e.code, TraceErrorCode::kInvalidArgument);
    EXPECT_NE(e.message.find("compressor_threads"), std::string::npos) << e.message;

    auto w = TraceWriter::create(path, test_header(), {}, &e);
    ASSERT_TRUE(w);
    fbs::QueueSubmitT submit;
    submit.submission_index = 3;  // the first must be 0
    fbs::RecordT r;
    r.body.Set(std::move(submit));
    EXPECT_EQ(w->append(r).code, TraceErrorCode::kInvalidArgument);
    fbs::MemoryContentsT contents;
    contents.hash = 1;
    fbs::RecordT c;
    c.body.Set(std::move(contents));
    EXPECT_EQ(w->append(c).code,
              TraceErrorCode::kInvalidArgument);  // contents go through add_contents
    fbs::RecordT empty;
    EXPECT_EQ(w->append(empty).code, TraceErrorCode::kInvalidArgument);
    const uint8_t garbage[16] = {0xff, 0xff, 0xff, 0x7f};
    EXPECT_EQ(w->append_record_bytes(garbage, sizeof garbage).code,
              TraceErrorCode::kInvalidArgument);
    ASSERT_FALSE(w->finish());
    fbs::CommandBufferEndT end;
    fbs::RecordT er;
    er.body.Set(end);
    EXPECT_EQ(w->append(er).code, TraceErrorCode::kInvalidArgument);  // after finish
}

TEST(TraceWriterRules, DiskFullSurfacesAsAnError) {
    // /dev/full accepts open() and fails every write with ENOSPC.
    TraceError e;
    auto w = TraceWriter::create("/dev/full", test_header(), {}, &e);
    if (!w) {
        EXPECT_EQ(e.code, TraceErrorCode::kIoError);
        EXPECT_NE(e.message.find("No space left"), std::string::npos) << e.message;
        return;
    }
    FAIL() << "writing the file header to /dev/full succeeded";
}

TEST(TraceWriterRules, WriteFailureInTheBackgroundIsReportedByAppendOrFinish) {
    // The file grows past RLIMIT_FSIZE while the compression thread writes chunks:
    // write() fails with EFBIG (SIGXFSZ ignored). The error must reach the caller.
    struct rlimit old {};
    ASSERT_EQ(getrlimit(RLIMIT_FSIZE, &old), 0);
    auto old_handler = std::signal(SIGXFSZ, SIG_IGN);
    struct rlimit small = old;
    small.rlim_cur = 64 << 10;
    ASSERT_EQ(setrlimit(RLIMIT_FSIZE, &small), 0);

    // One compression thread, and three that compress side by side (the first failed write
    // must stop the others' chunks too).
    std::vector<std::pair<std::string, TraceError>> firsts;  // path, first error
    for (uint32_t threads : {1u, 3u}) {
        const std::string path = temp_path("efbig" + std::to_string(threads) + ".clt");
        TraceError e;
        TraceWriterOptions options;
        options.chunk_raw_bytes = 16 << 10;
        options.zstd_level = 1;
        options.compressor_threads = threads;
        auto w = TraceWriter::create(path, test_header(), options, &e);
        TraceError first;
        if (w) {
            std::mt19937_64 rng(1);
            std::vector<uint64_t> noise(
                1024);  // incompressible: the file grows as fast as the data
            for (int i = 0; i < 64 && !first; ++i) {
                for (auto& x : noise) x = rng();
                uint64_t key;
                first = w->add_contents(noise.data(), noise.size() * 8, &key);
            }
            TraceError at_finish = w->finish();
            if (!first) first = at_finish;
            EXPECT_EQ(at_finish.code, TraceErrorCode::kIoError) << at_finish.message;
        } else {
            first = e;
        }
        firsts.emplace_back(path, first);
    }
    setrlimit(RLIMIT_FSIZE, &old);
    std::signal(SIGXFSZ, old_handler);
    for (const auto& [path, first] : firsts) {
        EXPECT_EQ(first.code, TraceErrorCode::kIoError);
        EXPECT_NE(first.message.find("File too large"), std::string::npos) << first.message;
        const std::string name = path.substr(path.rfind('/') + 1);
        EXPECT_NE(first.message.find(name + ": offset "), std::string::npos) << first.message;
        // What did reach the disk still reads back up to the damage.
        ReadResult read = read_all(path);
        ASSERT_TRUE(read.opened) << read.open_error.message;
        EXPECT_GT(read.damage_count, 0u);
    }
}

}  // namespace
}  // namespace clastrace::traces::testing
