// SPDX-License-Identifier: Apache-2.0
// The read-ahead thread's failures (docs/trace-format.md, "Reading ahead"): a read error, a
// chunk the file ends in, a payload that does not decompress and an allocation failure on the
// thread. A thread that threw (out of memory) or whose read failed has its chunk read again on
// the caller's thread, so a transient read error is recovered; the thread's other verdicts are
// what the caller's thread reports reading the same chunk itself (same records, same damage,
// file and offset included); the thread is gone with the reader.
#include "failing_source.h"
#include "records_chunks.h"
#include "trace_test_support.h"

#include "chunk_streams.h"
#include "file_format.h"

#include <gtest/gtest.h>

#include <cstring>
#include <map>
#include <optional>
#include <random>
#include <unistd.h>

namespace clastrace::traces::testing {
namespace {

namespace f = format;

// Above what a chunk's records and payloads need on the thread, below its chunk buffers.
constexpr size_t kChunkBufferBytes = 64u << 10;

// A frame loop in chunks of 300 KiB: every chunk but the first is read on the read-ahead thread.
class ReadAheadFailure : public ::testing::Test {
protected:
    void SetUp() override {
        path = temp_path("frames.clt");
        write_frames_trace(path, 600, 300u << 10);
        file = read_file(path);
        chunks = records_chunks(file);
        ASSERT_GE(chunks.size(), 5u);
        for (size_t i = 0; i + 1 < chunks.size(); ++i)
            ASSERT_GE(chunks[i].header.raw_size, 256u << 10);  // so the next one is read ahead
    }

    // The damaged copy of the trace, written beside it.
    std::string write_damaged(const std::vector<uint8_t>& bytes) {
        const std::string damaged = temp_path("damaged.clt");
        write_file(damaged, bytes);
        return damaged;
    }

    std::string path;
    std::vector<uint8_t> file;
    std::vector<ChunkAt> chunks;
};

// Every chunk read on the caller's thread: the read-ahead thread cannot take a chunk buffer, so
// every chunk it was given is read again there.
template <class Read>
ReadResult read_on_callers_thread(Read read) {
    FailingAllocations out_of_memory(kChunkBufferBytes);
    ReadResult r = read();
    EXPECT_GT(out_of_memory.failed(), 0u);
    return r;
}

void expect_same_read(const ReadResult& got, const ReadResult& expected) {
    EXPECT_EQ(got.opened, expected.opened);
    EXPECT_TRUE(got.records == expected.records)
        << got.records.size() << " records, expected " << expected.records.size();
    ASSERT_EQ(got.damage.size(), expected.damage.size()) << describe(got.damage);
    for (size_t i = 0; i < got.damage.size(); ++i) {
        EXPECT_EQ(got.damage[i].code, expected.damage[i].code) << got.damage[i].message;
        EXPECT_EQ(got.damage[i].file_offset, expected.damage[i].file_offset);
        EXPECT_EQ(got.damage[i].message, expected.damage[i].message);
    }
}

// The records of the chunks before chunk `k` of a clean read.
size_t records_before(const std::vector<ChunkAt>& chunks, size_t k) {
    size_t n = 0;
    for (size_t i = 0; i < k; ++i) n += chunks[i].header.record_count;
    return n;
}

TEST_F(ReadAheadFailure, AnAllocationFailureOnTheThreadHasItsChunkReadOnTheCallersThread) {
    const ReadResult clean = read_all(path);
    ASSERT_EQ(clean.damage_count, 0u) << describe(clean.damage);
    const ReadResult fell_back = read_on_callers_thread([&] { return read_all(path); });
    EXPECT_EQ(fell_back.damage_count, 0u) << describe(fell_back.damage);
    expect_same_read(fell_back, clean);
    EXPECT_EQ(fell_back.stats.chunks_read, clean.stats.chunks_read);
}

// A read of chunk 2 that fails as `failure` says (its range set here).
ReadResult read_failing(const std::vector<uint8_t>& file, const ChunkAt& c,
                        const std::shared_ptr<ReadFailure>& failure) {
    failure->from = c.offset;
    failure->to = c.offset + f::kChunkHeaderSize + c.header.compressed_size;
    TraceError e;
    return drain(open_failing(file, "failing.clt", failure, &e), e);
}

// Only the thread's read of chunk 2 fails: the caller's thread reads it again, and the read is
// the clean one.
TEST_F(ReadAheadFailure, AReadErrorOnTheThreadHasItsChunkReadAgainOnTheCallersThread) {
    const ReadResult clean = read_all(path);
    ASSERT_EQ(clean.damage_count, 0u) << describe(clean.damage);
    auto on_thread = std::make_shared<ReadFailure>();
    const ReadResult got = read_failing(file, chunks[2], on_thread);
    EXPECT_GE(on_thread->failed.load(), 1u);
    EXPECT_EQ(got.damage_count, 0u) << describe(got.damage);
    expect_same_read(got, clean);
    EXPECT_EQ(got.stats.chunks_read, clean.stats.chunks_read);
}

// The first read of chunk 2, whichever thread makes it (the read-ahead thread), fails once: a
// transient error costs nothing.
TEST_F(ReadAheadFailure, ATransientReadErrorIsRecoveredWithTheSameRecords) {
    const ReadResult clean = read_all(path);
    auto once = std::make_shared<ReadFailure>();
    once->read_ahead_thread_only = false;
    once->max_failures = 1;
    const ReadResult got = read_failing(file, chunks[2], once);
    EXPECT_EQ(once->failed.load(), 1u);
    EXPECT_EQ(got.damage_count, 0u) << describe(got.damage);
    expect_same_read(got, clean);
}

// Every read of chunk 2 fails: the error is the one the caller's thread gives reading it alone,
// naming the file and the offset, and the read stops there.
TEST_F(ReadAheadFailure, APersistentReadErrorIsTheErrorOfReadingOnTheCallersThread) {
    const ChunkAt& c = chunks[2];
    auto everywhere = std::make_shared<ReadFailure>();
    everywhere->read_ahead_thread_only = false;
    const ReadResult got = read_failing(file, c, everywhere);
    EXPECT_GE(everywhere->failed.load(), 2u);  // the thread's read, then the caller's

    auto alone = std::make_shared<ReadFailure>();
    alone->read_ahead_thread_only = false;
    expect_same_read(got, read_on_callers_thread([&] { return read_failing(file, c, alone); }));

    ASSERT_EQ(got.damage.size(), 1u) << describe(got.damage);
    const TraceError& err = got.damage[0];
    EXPECT_EQ(err.code, TraceErrorCode::kIoError);
    EXPECT_EQ(err.file_offset, c.offset);
    EXPECT_EQ(err.message, "failing.clt: offset " + std::to_string(c.offset) +
                               ": read failed: " + kInjectedReadError);
    EXPECT_EQ(got.records.size(), records_before(chunks, 2));
}

// The file ends inside chunk 3, which the thread reads: the truncation is reported at the
// chunk's size field with the file's path, as reading it on the caller's thread does.
TEST_F(ReadAheadFailure, AChunkTheFileEndsInIsReportedAsOnTheCallersThread) {
    const ChunkAt& c = chunks[3];
    const std::string cut =
        write_damaged({file.begin(), file.begin() + long(c.offset + f::kChunkHeaderSize + 100)});
    const ReadResult got = read_all(cut);
    expect_same_read(got, read_on_callers_thread([&] { return read_all(cut); }));
    ASSERT_EQ(got.damage.size(), 2u) << describe(got.damage);  // the trailer, then the chunk
    const TraceError& err = got.damage[1];
    EXPECT_EQ(err.code, TraceErrorCode::kTruncated) << err.message;
    EXPECT_EQ(err.file_offset, c.offset + offsetof(f::ChunkHeader, compressed_size));
    EXPECT_EQ(err.message.rfind(cut + ": offset ", 0), 0u) << err.message;
    EXPECT_EQ(got.records.size(), records_before(chunks, 3));
}

// The file shrinks under the reader (cut inside chunk 3 once it is open): the thread's read
// comes back short, so does the caller's read again, and the error names the file, the offset
// and what the read met.
TEST_F(ReadAheadFailure, AFileCutWhileReadIsReportedAsOnTheCallersThread) {
    const ChunkAt& c = chunks[3];
    const uint64_t cut_at = c.offset + f::kChunkHeaderSize + 100;
    const auto read_cut_while_open = [&] {
        const std::string shrinking = write_damaged(file);
        TraceError e;
        auto reader = TraceReader::open(shrinking, &e);
        EXPECT_EQ(::truncate(shrinking.c_str(), off_t(cut_at)), 0);
        return drain(std::move(reader), e);
    };
    const ReadResult got = read_cut_while_open();
    expect_same_read(got, read_on_callers_thread(read_cut_while_open));
    ASSERT_FALSE(got.damage.empty());
    const TraceError& err = got.damage[0];
    EXPECT_EQ(err.code, TraceErrorCode::kIoError) << err.message;
    EXPECT_EQ(err.file_offset, c.offset + f::kChunkHeaderSize);
    EXPECT_NE(err.message.find(": read failed: unexpected end of file"), std::string::npos)
        << err.message;
    EXPECT_EQ(got.records.size(), records_before(chunks, 3));
}

// Chunk 2's streams payload no longer decompresses (its checksum made to hold): the thread's
// verdict names the file and the byte, and the chunks after it are still read.
TEST_F(ReadAheadFailure, APayloadThatDoesNotDecompressIsReportedAsOnTheCallersThread) {
    const ChunkAt& c = chunks[2];
    const uint64_t payload = c.offset + f::kChunkHeaderSize;
    ASSERT_TRUE(f::is_streams_payload(file.data() + payload, c.header.compressed_size));
    std::vector<uint8_t> bytes = file;
    uint32_t sizes[2];  // one byte moves from the records frame to the contents frame
    std::memcpy(sizes, bytes.data() + payload + 4, sizeof sizes);
    sizes[0] += 1;
    sizes[1] -= 1;
    std::memcpy(bytes.data() + payload + 4, sizes, sizeof sizes);
    f::ChunkHeader h = c.header;
    h.payload_checksum = f::checksum(bytes.data() + payload, h.compressed_size);
    h.header_checksum = f::chunk_header_checksum(h);
    std::memcpy(bytes.data() + c.offset, &h, sizeof h);
    const std::string damaged = write_damaged(bytes);

    const ReadResult got = read_all(damaged);
    expect_same_read(got, read_on_callers_thread([&] { return read_all(damaged); }));
    ASSERT_FALSE(got.damage.empty());
    const TraceError& err = got.damage[0];
    EXPECT_EQ(err.code, TraceErrorCode::kDecompressFailed) << err.message;
    EXPECT_EQ(err.file_offset, payload + f::kStreamsHeaderSize);
    EXPECT_EQ(err.message.rfind(damaged + ": offset ", 0), 0u) << err.message;
    EXPECT_NE(err.message.find("chunk 2 streams payload"), std::string::npos) << err.message;
    EXPECT_GT(got.records.size(), records_before(chunks, 3) - c.header.record_count);
}

// Range 1 stored whole in chunk 0, then 500 other ranges' first contents (whole, 3 KB each), then
// range 1 again, a little changed: a delta whose base lies in chunk 0, which neither thread
// holds by then, so the read-ahead thread reads that chunk again itself.
void write_far_base_trace(const std::string& path) {
    TraceWriterOptions options;
    options.chunk_raw_bytes = 300u << 10;
    TraceError e;
    auto w = TraceWriter::create(path, test_header(), options, &e);
    ASSERT_TRUE(w) << e.message;
    std::map<uint64_t, std::vector<uint8_t>> bytes_by_key;
    std::vector<uint8_t> first(3000), other(3000);
    for (size_t i = 0; i < first.size(); ++i) first[i] = uint8_t(i * 7);
    append_build_snapshotting(*w, {{1, first.data(), first.size()}}, bytes_by_key);
    std::mt19937 rng(3);
    for (uint64_t range = 2; range < 502; ++range) {
        for (uint8_t& b : other) b = uint8_t(rng());
        append_build_snapshotting(*w, {{range, other.data(), other.size()}}, bytes_by_key);
    }
    first[10] ^= 1;
    append_build_snapshotting(*w, {{1, first.data(), first.size()}}, bytes_by_key);
    ASSERT_FALSE(w->finish());
    ASSERT_EQ(w->stats().contents_delta_stored, 1u);
}

// The thread's read of that base failing leaves the delta to the caller's thread, which reads
// the base itself: nothing lost, nothing reported.
TEST(ReadAheadFailures, ABaseTheThreadCannotReadIsReadOnTheCallersThread) {
    const std::string path = temp_path("far_base.clt");
    write_far_base_trace(path);
    const std::vector<uint8_t> file = read_file(path);
    const std::vector<ChunkAt> chunks = records_chunks(file);
    ASSERT_GE(chunks.size(), 5u);
    const ReadResult clean = read_all(path);
    ASSERT_EQ(clean.damage_count, 0u) << describe(clean.damage);
    EXPECT_EQ(clean.stats.deltas_decoded_ahead, 1u);

    auto on_thread = std::make_shared<ReadFailure>();
    on_thread->from = chunks[0].offset;
    on_thread->to = chunks[1].offset;
    TraceError e;
    const ReadResult got = drain(open_failing(file, "failing.clt", on_thread, &e), e);
    EXPECT_EQ(on_thread->failed.load(), 1u);
    EXPECT_EQ(got.damage_count, 0u) << describe(got.damage);
    expect_same_read(got, clean);
    EXPECT_EQ(got.stats.deltas_decoded_ahead, 0u);
}

// The thread is joined with the reader, whether its last job succeeded, threw or was never
// taken (the reader destroyed while the thread reads ahead).
TEST_F(ReadAheadFailure, TheThreadIsJoinedWithTheReaderWhateverItsLastJob) {
    const size_t before = thread_count();
    for (const bool out_of_memory : {false, true}) {
        for (const size_t records : {size_t{1}, records_before(chunks, 2), size_t{100'000}}) {
            SCOPED_TRACE(std::to_string(records) + " records, out of memory " +
                         std::to_string(out_of_memory));
            std::optional<FailingAllocations> failing;
            if (out_of_memory) failing.emplace(kChunkBufferBytes);
            TraceError e;
            auto reader = TraceReader::open(path, &e);
            ASSERT_TRUE(reader) << e.message;
            RecordView v;
            size_t n = 0;
            while (n < records && reader->next(&v)) ++n;
            EXPECT_EQ(thread_count(), before + 1);  // the read-ahead thread
            reader.reset();
            EXPECT_EQ(thread_count(), before);
        }
    }
}

}  // namespace
}  // namespace clastrace::traces::testing
