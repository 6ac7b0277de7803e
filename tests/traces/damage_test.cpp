// SPDX-License-Identifier: Apache-2.0
// Damaged files: each kind of damage gets its own error naming the file offset, and
// everything intact around the damage still reads.
#include "trace_test_support.h"

#include <clastrace/common/hex.h>
#include <clastrace/traces/records.h>

#include "byte_planes.h"
#include "file_format.h"

#include <gtest/gtest.h>

#include <zstd.h>

#include <algorithm>
#include <cmath>
#include <random>

namespace clastrace::traces::testing {
namespace {

namespace f = clastrace::traces::format;

// Chunk headers of a file, found by walking from the first chunk.
struct ChunkSpan {
    uint64_t offset;
    f::ChunkHeader header;
    uint64_t end() const { return offset + f::kChunkHeaderSize + header.compressed_size; }
};

uint64_t data_start(const std::vector<uint8_t>& file) {
    return f::kFileHeaderSize + f::align8(f::load<uint32_t>(file.data() + 12));
}

std::vector<ChunkSpan> chunks_of(const std::vector<uint8_t>& file) {
    std::vector<ChunkSpan> out;
    uint64_t at = data_start(file);
    while (at + f::kChunkHeaderSize <= file.size()) {
        f::ChunkHeader h;
        std::memcpy(&h, file.data() + at, sizeof h);
        if (h.magic != f::kChunkMagic) break;
        out.push_back({at, h});
        at += f::kChunkHeaderSize + h.compressed_size;
    }
    return out;
}

bool has_damage(const ReadResult& r, TraceErrorCode code, uint64_t offset) {
    return std::any_of(r.damage.begin(), r.damage.end(), [&](const TraceError& e) {
        return e.code == code && e.file_offset == offset;
    });
}
bool has_damage(const ReadResult& r, TraceErrorCode code) {
    return std::any_of(r.damage.begin(), r.damage.end(),
                       [&](const TraceError& e) { return e.code == code; });
}

size_t records_in(const std::vector<ChunkSpan>& chunks, size_t count) {
    size_t n = 0;
    for (size_t i = 0; i < count; ++i) n += chunks[i].header.record_count;
    return n;
}

void rewrite_chunk_header(std::vector<uint8_t>& file, uint64_t at, const f::ChunkHeader& h) {
    f::ChunkHeader c = h;
    c.header_checksum = f::chunk_header_checksum(c);
    std::memcpy(file.data() + at, &c, sizeof c);
}

// A records chunk around `raw` (already framed), with correct checksums.
std::vector<uint8_t> make_chunk(const std::vector<uint8_t>& raw, uint32_t number,
                                uint32_t records) {
    std::vector<uint8_t> compressed(ZSTD_compressBound(raw.size()));
    size_t n = ZSTD_compress(compressed.data(), compressed.size(), raw.data(), raw.size(), 3);
    compressed.resize(n);
    f::ChunkHeader h{};
    h.magic = f::kChunkMagic;
    h.kind = static_cast<uint16_t>(f::ChunkKind::kRecords);
    h.chunk_number = number;
    h.record_count = records;
    h.raw_size = static_cast<uint32_t>(raw.size());
    h.compressed_size = static_cast<uint32_t>(n);
    h.payload_checksum = f::checksum(compressed.data(), n);
    h.header_checksum = f::chunk_header_checksum(h);
    std::vector<uint8_t> out(sizeof h);
    std::memcpy(out.data(), &h, sizeof h);
    out.insert(out.end(), compressed.begin(), compressed.end());
    return out;
}

void frame(std::vector<uint8_t>& raw, const uint8_t* data, size_t size, uint32_t kind) {
    uint32_t head[2] = {static_cast<uint32_t>(size), kind};
    size_t at = raw.size();
    raw.resize(at + 8 + f::align8(size), 0);
    std::memcpy(raw.data() + at, head, 8);
    std::memcpy(raw.data() + at + 8, data, size);
}

void frame(std::vector<uint8_t>& raw, const fbs::RecordT& r) {
    flatbuffers::FlatBufferBuilder b;
    b.Finish(fbs::Record::Pack(b, &r));
    frame(raw, b.GetBufferPointer(), b.GetSize(), static_cast<uint32_t>(r.body.type));
}

// The file header of a freshly written empty trace: a valid prefix for crafted chunks.
std::vector<uint8_t> header_only_prefix() {
    const std::string path = temp_path("prefix.clt");
    TraceError e;
    auto w = TraceWriter::create(path, test_header(), {}, &e);
    EXPECT_TRUE(w);
    EXPECT_FALSE(w->finish());
    std::vector<uint8_t> file = read_file(path);
    file.resize(data_start(file));
    return file;
}

// One chunk of the framed `raw` claiming `records` records, after a valid header; returns the
// file and the chunk's offset.
std::vector<uint8_t> file_of_raw(const std::vector<uint8_t>& raw, uint32_t records,
                                 uint64_t* chunk_at) {
    std::vector<uint8_t> file = header_only_prefix();
    *chunk_at = file.size();
    std::vector<uint8_t> chunk = make_chunk(raw, 0, records);
    file.insert(file.end(), chunk.begin(), chunk.end());
    return file;
}

// One chunk of `records` after a valid header; returns the file and the chunk's offset.
std::vector<uint8_t> file_of(const std::vector<fbs::RecordT>& records, uint64_t* chunk_at) {
    std::vector<uint8_t> raw;
    for (const fbs::RecordT& r : records) frame(raw, r);
    return file_of_raw(raw, static_cast<uint32_t>(records.size()), chunk_at);
}

fbs::RecordT command_buffer_end() {
    fbs::RecordT r;
    r.body.Set(fbs::CommandBufferEndT{});
    return r;
}

class DamagedTrace : public ::testing::Test {
protected:
    explicit DamagedTrace(int frames = 30) : frames_(frames) {}
    void SetUp() override {
        path_ = temp_path("good.clt");
        // Whole contents: each chunk's damage stays in it. (Deltas carry a damaged chunk's
        // loss on to the deltas built on it: DeltasWhoseBaseWasInADamagedChunk... below.)
        TraceWriterOptions whole;
        whole.delta_contents = false;
        written_ = write_frames_trace(path_, frames_, 6000, whole);
        file_ = read_file(path_);
        chunks_ = chunks_of(file_);
        ASSERT_GE(chunks_.size(), 6u);  // several record chunks + the index chunk
        ASSERT_EQ(chunks_.back().header.kind, static_cast<uint16_t>(f::ChunkKind::kIndex));
        total_records_ = records_in(chunks_, chunks_.size() - 1);
        ReadResult clean = read_all_memory(file_);
        ASSERT_EQ(clean.damage_count, 0u) << describe(clean.damage);
        ASSERT_EQ(clean.records.size(), total_records_);
    }
    int frames_;
    std::string path_;
    std::vector<fbs::RecordT> written_;
    std::vector<uint8_t> file_;
    std::vector<ChunkSpan> chunks_;
    size_t total_records_ = 0;
};

TEST(TraceDamage, EmptyFileIsAnError) {
    ReadResult r = read_all_memory({});
    EXPECT_FALSE(r.opened);
    EXPECT_EQ(r.open_error.code, TraceErrorCode::kTruncated);
    EXPECT_NE(r.open_error.message.find("empty file"), std::string::npos) << r.open_error.message;
}

TEST(TraceDamage, WrongMagicIsNotATrace) {
    std::vector<uint8_t> file = header_only_prefix();
    file[0] = 'X';
    ReadResult r = read_all_memory(file);
    EXPECT_FALSE(r.opened);
    EXPECT_EQ(r.open_error.code, TraceErrorCode::kNotATrace);
    EXPECT_EQ(r.open_error.message, "memory.clt: offset 0: not a clastrace trace (wrong magic)");
    std::vector<uint8_t> text = {'h', 'e', 'l', 'l', 'o', ' ', 'w', 'o', 'r', 'l', 'd', '\n'};
    EXPECT_EQ(read_all_memory(text).open_error.code, TraceErrorCode::kNotATrace);
}

TEST(TraceDamage, NewerMajorVersionIsRefused) {
    std::vector<uint8_t> file = header_only_prefix();
    uint16_t major = 2;
    std::memcpy(file.data() + 8, &major, 2);
    ReadResult r = read_all_memory(file);
    EXPECT_FALSE(r.opened);
    EXPECT_EQ(r.open_error.code, TraceErrorCode::kUnsupportedVersion);
    EXPECT_EQ(r.open_error.file_offset, 8u);
    EXPECT_NE(r.open_error.message.find("format version 2."), std::string::npos)
        << r.open_error.message;
    EXPECT_NE(r.open_error.message.find("is not supported (this reader reads 1.x)"),
              std::string::npos)
        << r.open_error.message;
}

TEST_F(DamagedTrace, NewerMinorVersionStillReads) {
    std::vector<uint8_t> file = file_;
    f::FileHeader fh;
    std::memcpy(&fh, file.data(), sizeof fh);
    fh.version_minor = f::kVersionMinor + 1;
    fh.checksum = f::file_header_checksum(fh, file.data() + 32, fh.trace_header_size);
    std::memcpy(file.data(), &fh, sizeof fh);
    TraceError e;
    auto reader = TraceReader::open_memory(file.data(), file.size(), "minor.clt", &e);
    ASSERT_TRUE(reader) << e.message;
    EXPECT_EQ(reader->version_minor(), f::kVersionMinor + 1);
    ReadResult r = read_all_memory(file);
    EXPECT_EQ(r.damage_count, 0u) << describe(r.damage);
    EXPECT_EQ(r.records.size(), total_records_);
}

TEST_F(DamagedTrace, CutAtEveryChunkBoundaryKeepsEveryCompleteChunk) {
    for (size_t i = 0; i < chunks_.size(); ++i) {
        std::vector<uint8_t> cut(file_.begin(),
                                 file_.begin() + static_cast<long>(chunks_[i].offset));
        ReadResult r = read_all_memory(cut);
        ASSERT_TRUE(r.opened) << i;
        EXPECT_EQ(r.records.size(), records_in(chunks_, i)) << "cut before chunk " << i;
        EXPECT_TRUE(has_damage(r, TraceErrorCode::kTruncated, cut.size())) << describe(r.damage);
        EXPECT_FALSE(r.has_index);
    }
}

TEST_F(DamagedTrace, CutInsideChunksKeepsTheChunksBefore) {
    for (size_t i = 0; i + 1 < chunks_.size(); ++i) {
        const ChunkSpan& c = chunks_[i];
        for (uint64_t at :
             {c.offset + 1, c.offset + 20, c.offset + f::kChunkHeaderSize,
              c.offset + f::kChunkHeaderSize + 1, (c.offset + c.end()) / 2, c.end() - 1}) {
            std::vector<uint8_t> cut(file_.begin(), file_.begin() + static_cast<long>(at));
            ReadResult r = read_all_memory(cut);
            ASSERT_TRUE(r.opened);
            EXPECT_EQ(r.records.size(), records_in(chunks_, i))
                << "cut at " << at << " inside chunk " << i;
            // The cut chunk is named by its own offset (header cut) or its size field.
            bool named = has_damage(r, TraceErrorCode::kTruncated, c.offset) ||
                         has_damage(r, TraceErrorCode::kTruncated,
                                    c.offset + offsetof(f::ChunkHeader, compressed_size));
            EXPECT_TRUE(named) << "cut at " << at << "\n" << describe(r.damage);
        }
    }
}

// A smaller trace (still 6+ chunks) for the tests that try every byte.
class SmallDamagedTrace : public DamagedTrace {
protected:
    SmallDamagedTrace() : DamagedTrace(7) {}
};

TEST_F(SmallDamagedTrace, CutAtEveryByteNeverLosesACompleteChunk) {
    // Every possible cut of the file: all records of the chunks wholly before the cut
    // come back, and damage is reported unless the cut is the whole file.
    for (size_t at = 0; at < file_.size(); at += 1) {
        std::vector<uint8_t> cut(file_.begin(), file_.begin() + static_cast<long>(at));
        ReadResult r = read_all_memory(cut);
        size_t complete = 0;
        while (complete < chunks_.size() - 1 && chunks_[complete].end() <= at) ++complete;
        if (!r.opened) {
            ASSERT_LT(at, data_start(file_) + 8)
                << "only a cut header may make the file unopenable";
            continue;
        }
        ASSERT_EQ(r.records.size(), records_in(chunks_, complete)) << "cut at " << at;
        ASSERT_GT(r.damage_count, 0u) << "cut at " << at;
    }
}

TEST_F(DamagedTrace, FlippedBitInAChunkIsReportedAndTheOtherChunksRead) {
    for (size_t i = 0; i + 1 < chunks_.size(); ++i) {
        const ChunkSpan& c = chunks_[i];
        std::vector<uint8_t> file = file_;
        uint64_t at = c.offset + f::kChunkHeaderSize + c.header.compressed_size / 2;
        file[at] ^= 0x10;
        ReadResult r = read_all_memory(file);
        ASSERT_TRUE(r.opened);
        EXPECT_EQ(r.records.size(), total_records_ - c.header.record_count)
            << "flip in chunk " << i;
        ASSERT_TRUE(
            has_damage(r, TraceErrorCode::kChecksumMismatch, c.offset + f::kChunkHeaderSize))
            << describe(r.damage);
        const std::string expect = "memory.clt: offset " +
                                   std::to_string(c.offset + f::kChunkHeaderSize) + ": chunk " +
                                   std::to_string(i) + " checksum mismatch (stored 0x";
        EXPECT_EQ(r.damage[0].message.rfind(expect, 0), 0u) << r.damage[0].message;
    }
}

TEST_F(DamagedTrace, FlippedBitInAChunkHeaderIsReportedAndReadingResumes) {
    for (size_t i = 0; i + 1 < chunks_.size(); ++i) {
        std::vector<uint8_t> file = file_;
        file[chunks_[i].offset + 17] ^= 0x01;  // raw_size
        ReadResult r = read_all_memory(file);
        ASSERT_TRUE(r.opened);
        EXPECT_EQ(r.records.size(), total_records_ - chunks_[i].header.record_count);
        EXPECT_TRUE(has_damage(r, TraceErrorCode::kChecksumMismatch, chunks_[i].offset))
            << describe(r.damage);
    }
}

TEST_F(SmallDamagedTrace, EverySingleBitFlipIsReported) {
    // Flip each bit of every 7th byte (all bytes of the headers): nothing goes unnoticed,
    // nothing crashes, and intact chunks keep coming back.
    for (size_t at = 0; at < file_.size(); ++at) {
        bool header_byte = at < data_start(file_) + 64 || at + 64 > file_.size();
        if (!header_byte && at % 7 != 0) continue;
        for (int bit = 0; bit < 8; ++bit) {
            std::vector<uint8_t> file = file_;
            file[at] ^= static_cast<uint8_t>(1u << bit);
            ReadResult r = read_all_memory(file);
            if (!r.opened) {
                ASSERT_LT(at, 16u) << "only magic/version flips may refuse the file";
                continue;
            }
            ASSERT_GT(r.damage_count, 0u)
                << "flip of bit " << bit << " at offset " << at << " went unnoticed";
        }
    }
}

TEST_F(DamagedTrace, ChunkClaimingTwoGibibytesIsRefusedBeforeAllocating) {
    for (bool raw_field : {true, false}) {
        std::vector<uint8_t> file = file_;
        f::ChunkHeader h = chunks_[2].header;
        if (raw_field) {
            h.raw_size = 0x80000000u;
        } else {
            h.compressed_size = 0x80000000u;
        }
        rewrite_chunk_header(file, chunks_[2].offset, h);
        ReadResult r = read_all_memory(file);
        ASSERT_TRUE(r.opened);
        uint64_t field =
            chunks_[2].offset + (raw_field ? offsetof(f::ChunkHeader, raw_size)
                                           : offsetof(f::ChunkHeader, compressed_size));
        EXPECT_TRUE(has_damage(r, TraceErrorCode::kLengthOutOfRange, field)) << describe(r.damage);
        // Resynchronisation finds chunk 3 again: only chunk 2's records are lost.
        EXPECT_EQ(r.records.size(), total_records_ - chunks_[2].header.record_count);
    }
}

TEST(TraceDamage, TraceHeaderClaimingTwoGibibytesIsReported) {
    std::vector<uint8_t> file = header_only_prefix();
    uint32_t huge = 0x80000000u;
    std::memcpy(file.data() + 12, &huge, 4);
    ReadResult r = read_all_memory(file);
    ASSERT_TRUE(r.opened);
    EXPECT_TRUE(has_damage(r, TraceErrorCode::kLengthOutOfRange, 12)) << describe(r.damage);
}

TEST(TraceDamage, RecordClaimingTwoGibibytesIsReported) {
    std::vector<uint8_t> raw;
    fbs::CommandBufferEndT end;
    end.command_buffer = 5;
    fbs::RecordT r;
    r.body.Set(end);
    frame(raw, r);
    size_t second = raw.size();
    frame(raw, r);
    uint32_t huge = 0x80000000u;
    std::memcpy(raw.data() + second, &huge, 4);
    uint64_t chunk_at = 0;
    std::vector<uint8_t> file = file_of_raw(raw, 2, &chunk_at);
    ReadResult read = read_all_memory(file);
    ASSERT_TRUE(read.opened);
    EXPECT_EQ(read.records.size(), 1u);
    ASSERT_TRUE(has_damage(read, TraceErrorCode::kLengthOutOfRange, chunk_at))
        << describe(read.damage);
    auto it = std::find_if(read.damage.begin(), read.damage.end(), [](const TraceError& e) {
        return e.code == TraceErrorCode::kLengthOutOfRange;
    });
    EXPECT_NE(it->message.find("record 1 (raw offset " + std::to_string(second) +
                               "): claims 2147483648 bytes"),
              std::string::npos)
        << it->message;
}

TEST(TraceDamage, SnapshotOfMissingContentsIsReportedWithItsChunk) {
    std::vector<uint8_t> raw;
    fbs::CmdCopyBufferT copy;
    copy.inputs.emplace_back(1, 0, 0x1000, 16, 0xfeedfacecafebeefull);
    fbs::RecordT r;
    r.body.Set(std::move(copy));
    frame(raw, r);
    frame(raw, command_buffer_end());
    uint64_t chunk_at = 0;
    std::vector<uint8_t> file = file_of_raw(raw, 2, &chunk_at);
    ReadResult read = read_all_memory(file);
    ASSERT_TRUE(read.opened);
    ASSERT_TRUE(has_damage(read, TraceErrorCode::kMissingContents, chunk_at))
        << describe(read.damage);
    EXPECT_NE(describe(read.damage)
                  .find("refers to contents 0xfeedfacecafebeef that no earlier record defines"),
              std::string::npos);
    ASSERT_EQ(read.records.size(), 1u);  // the copy is not handed out, the record after it is
    EXPECT_EQ(read.records[0].body.type, fbs::RecordBody::CommandBufferEnd);
}

// CmdTraceRays inputs and DeviceAddressWrites writes are checked like every other snapshot: a
// wrong hash names missing contents, a size the contents do not hold (cut short) a mismatch.
// The record is not handed out; the record after it is.
TEST(TraceDamage, BadSnapshotsOfRaysAndAddressWritesAreReportedWithTheirChunk) {
    for (fbs::RecordBody kind :
         {fbs::RecordBody::CmdTraceRays, fbs::RecordBody::DeviceAddressWrites})
        for (bool truncated : {false, true}) {
            SCOPED_TRACE(std::string(fbs::EnumNameRecordBody(kind)) +
                         (truncated ? " truncated" : " wrong hash"));
            std::vector<uint8_t> raw;
            fbs::MemoryContentsT c;
            c.bytes.assign(24, 0x3c);
            c.hash = f::content_key(c.bytes.data(), c.bytes.size(), 0, 64);
            const uint64_t stored = c.hash;
            fbs::RecordT cr;
            cr.body.Set(std::move(c));
            frame(raw, cr);
            const fbs::MemorySnapshot snapshot(0xb0, 8, 0xb008, truncated ? 48 : 24,
                                               truncated ? stored : stored ^ 0x10);
            fbs::RecordT bad;
            if (kind == fbs::RecordBody::CmdTraceRays) {
                fbs::CmdTraceRaysT rays;
                rays.inputs = {snapshot};
                bad.body.Set(std::move(rays));
            } else {
                fbs::DeviceAddressWritesT writes;
                writes.writes = {snapshot};
                bad.body.Set(std::move(writes));
            }
            frame(raw, bad);
            frame(raw, command_buffer_end());
            uint64_t chunk_at = 0;
            std::vector<uint8_t> file = file_of_raw(raw, 3, &chunk_at);
            ReadResult read = read_all_memory(file);
            ASSERT_TRUE(read.opened);
            const TraceErrorCode code =
                truncated ? TraceErrorCode::kContentMismatch : TraceErrorCode::kMissingContents;
            EXPECT_TRUE(has_damage(read, code, chunk_at)) << describe(read.damage);
            EXPECT_NE(describe(read.damage).find("chunk 0 record 2 (raw offset "),
                      std::string::npos)
                << describe(read.damage);
            EXPECT_NE(describe(read.damage)
                          .find(std::string("(") + fbs::EnumNameRecordBody(kind) +
                                "): snapshot of address 0x000000000000b008"),
                      std::string::npos)
                << describe(read.damage);
            ASSERT_EQ(read.records.size(), 2u);  // the contents and the end, not the bad record
            EXPECT_EQ(read.records[0].body.type, fbs::RecordBody::MemoryContents);
            EXPECT_EQ(read.records[1].body.type, fbs::RecordBody::CommandBufferEnd);
        }
}

TEST(TraceDamage, ContentsThatDoNotHashToTheirKeyAreReported) {
    std::vector<uint8_t> raw;
    fbs::MemoryContentsT c;
    c.bytes = {1, 2, 3, 4};
    c.hash = f::content_key(c.bytes.data(), 4, 0, 64) ^ 1;
    fbs::RecordT r;
    r.body.Set(std::move(c));
    frame(raw, r);
    uint64_t chunk_at = 0;
    const std::vector<uint8_t> file = file_of_raw(raw, 1, &chunk_at);
    ReadResult read = read_all_memory(file);
    EXPECT_TRUE(has_damage(read, TraceErrorCode::kContentMismatch, chunk_at))
        << describe(read.damage);
    EXPECT_TRUE(read.records.empty());

    // The faster setting trusts the writer's keys: the chunk checksum still holds, so
    // this mis-keyed record is handed out. That is the accuracy the option gives up.
    TraceReaderOptions fast;
    fast.verify_content_keys = false;
    TraceError e;
    auto reader = TraceReader::open_memory(file.data(), file.size(), "fast.clt", &e, fast);
    ASSERT_TRUE(reader);
    RecordView v;
    EXPECT_TRUE(reader->next(&v));
    EXPECT_EQ(v.kind, fbs::RecordBody::MemoryContents);
}

// read_contents keeps the real bytes it hands out for the next reading (replay reads a content
// at every snapshot naming it): bytes failing their key are never kept, and contents defined
// again by a later record are read from that record, as without the cache.
TEST(TraceDamage, ReadContentsKeepsNoBytesFailingTheirKeyNorThoseOfAContentDefinedAgain) {
    fbs::MemoryContentsT good;
    good.bytes = {1, 2, 3, 4};
    good.hash = f::content_key(good.bytes.data(), 4, 0, 64);
    fbs::MemoryContentsT mis_keyed = good;
    mis_keyed.bytes = {9, 9, 9, 9};
    std::vector<uint8_t> raw;
    for (const fbs::MemoryContentsT& c : {good, mis_keyed}) {
        fbs::RecordT r;
        r.body.Set(fbs::MemoryContentsT(c));
        frame(raw, r);
    }
    uint64_t chunk_at = 0;
    const std::vector<uint8_t> file = file_of_raw(raw, 2, &chunk_at);
    TraceReaderOptions fast;  // trusts the keys in the scan: read_contents checks them
    fast.verify_content_keys = false;
    TraceError e;
    auto reader = TraceReader::open_memory(file.data(), file.size(), "again.clt", &e, fast);
    ASSERT_TRUE(reader);
    RecordView v;
    ASSERT_TRUE(reader->next(&v));
    std::vector<uint8_t> got;
    for (int reading = 0; reading < 2; ++reading) {
        ASSERT_FALSE(reader->read_contents(good.hash, &got));
        EXPECT_EQ(got, good.bytes);
    }
    ASSERT_TRUE(reader->next(&v));  // the same key, other bytes: read from here on
    for (int reading = 0; reading < 2; ++reading) {
        const TraceError err = reader->read_contents(good.hash, &got);
        EXPECT_EQ(err.code, TraceErrorCode::kContentMismatch) << err.message;
        EXPECT_EQ(err.file_offset, chunk_at);
        EXPECT_NE(err.message.find("hold bytes that hash differently"), std::string::npos);
    }
}

TEST(TraceDamage, RecordFailingTheVerifierIsSkippedAndTheNextOneRead) {
    std::vector<uint8_t> raw;
    std::vector<uint8_t> junk(24, 0xff);  // root offset points far outside
    frame(raw, junk.data(), junk.size(), 3);
    frame(raw, command_buffer_end());
    uint64_t chunk_at = 0;
    std::vector<uint8_t> file = file_of_raw(raw, 2, &chunk_at);
    ReadResult read = read_all_memory(file);
    ASSERT_TRUE(has_damage(read, TraceErrorCode::kInvalidRecord, chunk_at))
        << describe(read.damage);
    EXPECT_NE(describe(read.damage).find("fails the FlatBuffers verifier"), std::string::npos);
    ASSERT_EQ(read.records.size(), 1u);
}

// The read-ahead task verifies a chunk's records before the reader's thread reads them (which
// then skips the verifier for those): a record failing it in a chunk read ahead is still
// reported and skipped, and the records around it read.
TEST(TraceDamage, RecordFailingTheVerifierInAChunkReadAheadIsSkippedAndTheNextOneRead) {
    fbs::MemoryContentsT big;  // a first chunk big enough for the next one to be read ahead
    big.bytes.assign(300u << 10, 7);
    big.hash = f::content_key(big.bytes.data(), big.bytes.size(), 0, 64);
    fbs::RecordT contents;
    contents.body.Set(fbs::MemoryContentsT(big));
    std::vector<uint8_t> first, second;
    frame(first, contents);
    frame(second, command_buffer_end());
    std::vector<uint8_t> junk(24, 0xff);  // root offset points far outside
    frame(second, junk.data(), junk.size(), 3);
    frame(second, command_buffer_end());
    std::vector<uint8_t> file = header_only_prefix();
    const std::vector<uint8_t> chunk0 = make_chunk(first, 0, 1);
    file.insert(file.end(), chunk0.begin(), chunk0.end());
    const uint64_t chunk_at = file.size();
    const std::vector<uint8_t> chunk1 = make_chunk(second, 1, 3);
    file.insert(file.end(), chunk1.begin(), chunk1.end());
    ReadResult read = read_all_memory(file);
    ASSERT_TRUE(has_damage(read, TraceErrorCode::kInvalidRecord, chunk_at))
        << describe(read.damage);
    EXPECT_NE(describe(read.damage).find("chunk 1 record 2 (raw offset 40)"), std::string::npos)
        << describe(read.damage);
    EXPECT_NE(describe(read.damage).find("fails the FlatBuffers verifier"), std::string::npos);
    ASSERT_EQ(read.records.size(), 3u);
}

TEST_F(DamagedTrace, BytesAfterTheTrailerAreReported) {
    std::vector<uint8_t> file = file_;
    file.insert(file.end(), {1, 2, 3, 4, 5});
    ReadResult r = read_all_memory(file);
    ASSERT_TRUE(r.opened);
    EXPECT_EQ(r.records.size(), total_records_);
    EXPECT_TRUE(has_damage(r, TraceErrorCode::kTrailingBytes, file_.size())) << describe(r.damage);
}

TEST_F(DamagedTrace, ReorderedChunksAreReported) {
    // Swap chunks 1 and 2 (both intact): numbering and submission counts disagree.
    std::vector<uint8_t> file(file_.begin(), file_.begin() + static_cast<long>(chunks_[1].offset));
    file.insert(file.end(), file_.begin() + static_cast<long>(chunks_[2].offset),
                file_.begin() + static_cast<long>(chunks_[2].end()));
    file.insert(file.end(), file_.begin() + static_cast<long>(chunks_[1].offset),
                file_.begin() + static_cast<long>(chunks_[1].end()));
    file.insert(file.end(), file_.begin() + static_cast<long>(chunks_[3].offset), file_.end());
    ReadResult r = read_all_memory(file);
    ASSERT_TRUE(r.opened);
    EXPECT_TRUE(has_damage(r, TraceErrorCode::kBadChunk)) << describe(r.damage);
}

// ---------------------------------------------------------------------------
// Delta contents (MemoryContentsDelta, format 1.7) whose base cannot serve: each is reported with its
// chunk's offset and the base it names, never handed out, and never crashes the reader.

// Whole contents of `bytes`, keyed as the writer keys them.
fbs::RecordT whole_contents(const std::vector<uint8_t>& bytes) {
    fbs::MemoryContentsT c;
    c.bytes = bytes;
    c.hash = f::content_key(bytes.data(), bytes.size(), 0, 64);
    fbs::RecordT r;
    r.body.Set(std::move(c));
    return r;
}

// `real` stored XOR `base` (naming base_hash), keyed by the real bytes; with byte_planes 4 the
// XOR is laid out in planes as the writer lays it (any other value is stored as given).
fbs::RecordT delta_contents(const std::vector<uint8_t>& real, const std::vector<uint8_t>& base,
                            uint64_t base_hash, uint8_t byte_planes = 0) {
    fbs::MemoryContentsDeltaT c;
    c.hash = f::content_key(real.data(), real.size(), 0, 64);
    c.byte_planes = byte_planes;
    c.base_hash = base_hash;
    std::vector<uint8_t> x = real;
    for (size_t i = 0; i < x.size() && i < base.size(); ++i) x[i] ^= base[i];
    c.bytes = x;
    if (byte_planes == 4) f::xor_to_byte_planes(real.data(), base.data(), x.size(), c.bytes.data());
    fbs::RecordT r;
    r.body.Set(std::move(c));
    return r;
}

uint64_t key_of(const std::vector<uint8_t>& bytes) {
    return f::content_key(bytes.data(), bytes.size(), 0, 64);
}

// Laid out as is and in byte planes (67 bytes: a tail of 3 outside the planes), a chain of two.
TEST(TraceDamage, DeltaWithItsBaseDecodesToTheRealBytes) {
    for (uint8_t planes : {0, 4}) {
        SCOPED_TRACE(int(planes));
        std::vector<uint8_t> base(67), real(67), next(67);
        for (size_t i = 0; i < base.size(); ++i) {
            base[i] = uint8_t(i * 7);
            real[i] = uint8_t(i * 7 + (i % 5 == 0));
            next[i] = uint8_t(real[i] ^ (i > 60 ? 0x80 : 0));
        }
        uint64_t chunk_at = 0;
        ReadResult read = read_all_memory(
            file_of({whole_contents(base), delta_contents(real, base, key_of(base), planes),
                     delta_contents(next, real, key_of(real), planes)},
                    &chunk_at));
        // (the crafted file has no trailer: that is its only damage)
        ASSERT_EQ(read.damage_count, 1u) << describe(read.damage);
        ASSERT_TRUE(has_damage(read, TraceErrorCode::kTruncated));
        ASSERT_EQ(read.records.size(), 3u);
        const auto* decoded = read.records[1].body.AsMemoryContentsDelta();
        ASSERT_TRUE(decoded);
        EXPECT_EQ(decoded->bytes, real);  // handed out decoded: consumers see the real bytes
        EXPECT_EQ(decoded->base_hash, key_of(base));
        ASSERT_TRUE(read.records[2].body.AsMemoryContentsDelta());
        EXPECT_EQ(read.records[2].body.AsMemoryContentsDelta()->bytes, next);
    }
}

TEST(TraceDamage, DeltaNamingAnUndefinedBaseIsMissingContents) {
    const std::vector<uint8_t> real(32, 3), base(32, 1);
    fbs::CmdCopyBufferT copy;
    copy.inputs.emplace_back(1, 0, 0x1000, 32, key_of(real));
    fbs::RecordT uses;
    uses.body.Set(std::move(copy));
    uint64_t chunk_at = 0;
    ReadResult read = read_all_memory(
        file_of({delta_contents(real, base, 0xdeadbeef00000001ull), uses, command_buffer_end()},
                &chunk_at));
    ASSERT_TRUE(read.opened);
    EXPECT_TRUE(has_damage(read, TraceErrorCode::kMissingContents, chunk_at))
        << describe(read.damage);
    EXPECT_NE(describe(read.damage)
                  .find("chunk 0 record 1 (raw offset 0): delta contents " +
                        common::hex(key_of(real), 16) +
                        " name the base 0xdeadbeef00000001, which no earlier record defines"),
              std::string::npos)
        << describe(read.damage);
    // Neither the delta nor the copy reading it is handed out; the record after them is.
    ASSERT_EQ(read.records.size(), 1u) << describe(read.damage);
    EXPECT_EQ(read.records[0].body.type, fbs::RecordBody::CommandBufferEnd);
}

// A cycle (each delta the other's base) and a delta that is its own base: no base precedes its
// delta, so neither decodes, and the walk through bases ends.
TEST(TraceDamage, DeltasInACycleOrTheirOwnBaseAreMissingContents) {
    const std::vector<uint8_t> a(40, 0x11), b(40, 0x22);
    uint64_t chunk_at = 0;
    ReadResult read =
        read_all_memory(file_of({delta_contents(a, b, key_of(b)), delta_contents(b, a, key_of(a)),
                                 delta_contents(a, a, key_of(a)), command_buffer_end()},
                                &chunk_at));
    ASSERT_TRUE(read.opened);
    EXPECT_EQ(std::count_if(read.damage.begin(), read.damage.end(),
                            [&](const TraceError& e) {
                                return e.code == TraceErrorCode::kMissingContents &&
                                       e.file_offset == chunk_at;
                            }),
              3)
        << describe(read.damage);
    ASSERT_EQ(read.records.size(), 1u);
    EXPECT_EQ(read.records[0].body.type, fbs::RecordBody::CommandBufferEnd);
}

TEST(TraceDamage, DeltaOfAnotherSizeOrAnUnknownLayoutIsAContentMismatch) {
    const std::vector<uint8_t> base(16, 5), real(24, 6), same_size(16, 8);
    uint64_t chunk_at = 0;
    ReadResult read =
        read_all_memory(file_of({whole_contents(base), delta_contents(real, base, key_of(base)),
                                 delta_contents(same_size, base, key_of(base), 7)},
                                &chunk_at));
    ASSERT_TRUE(read.opened);
    EXPECT_TRUE(has_damage(read, TraceErrorCode::kContentMismatch, chunk_at));
    EXPECT_NE(describe(read.damage).find("hold 24 bytes but their base"), std::string::npos)
        << describe(read.damage);
    EXPECT_NE(describe(read.damage)
                  .find("lay their XOR out in 7 byte planes, which this reader does not know"),
              std::string::npos)
        << describe(read.damage);
    EXPECT_EQ(read.records.size(), 1u);  // the base alone
}

// A delta XORed against the wrong base of the right size decodes to bytes that do not hash to
// its key: the key check (on in read_all) catches it.
TEST(TraceDamage, DeltaAgainstTheWrongBaseFailsItsKey) {
    const std::vector<uint8_t> base(16, 5), other(16, 4), real(16, 6);
    uint64_t chunk_at = 0;
    ReadResult read = read_all_memory(file_of({whole_contents(base), whole_contents(other),
                                               delta_contents(real, other, key_of(base))},
                                              &chunk_at));
    EXPECT_TRUE(has_damage(read, TraceErrorCode::kContentMismatch, chunk_at))
        << describe(read.damage);
    EXPECT_EQ(read.records.size(), 2u);
}

// A damaged chunk takes its contents with it, and so the deltas built on them in later chunks:
// those are missing_contents naming their own chunk, while the rest of the file still reads.
TEST(TraceDamage, DeltasWhoseBaseWasInADamagedChunkAreMissingContents) {
    const std::string path = temp_path("delta_damaged_base.clt");
    write_frames_trace(path, 30, 6000);
    std::vector<uint8_t> file = read_file(path);
    std::vector<ChunkSpan> chunks = chunks_of(file);
    ASSERT_GE(chunks.size(), 4u);
    file[chunks[0].offset + f::kChunkHeaderSize + 3] ^= 0x40;  // chunk 0's payload
    ReadResult read = read_all_memory(file);
    ASSERT_TRUE(read.opened);
    EXPECT_TRUE(has_damage(read, TraceErrorCode::kChecksumMismatch)) << describe(read.damage);
    bool later_delta_lost = false;
    for (const TraceError& e : read.damage)
        later_delta_lost |= e.code == TraceErrorCode::kMissingContents &&
                            e.file_offset > chunks[0].offset &&
                            e.message.find("delta contents") != std::string::npos;
    EXPECT_TRUE(later_delta_lost) << describe(read.damage);
    EXPECT_GT(read.records.size(), 0u);
}

// Records framed into one records chunk each (numbered in order), after a valid header.
std::vector<uint8_t> file_of_chunks(const std::vector<std::vector<fbs::RecordT>>& chunks) {
    std::vector<uint8_t> file = header_only_prefix();
    uint32_t number = 0;
    for (const std::vector<fbs::RecordT>& records : chunks) {
        std::vector<uint8_t> raw;
        for (const fbs::RecordT& r : records) frame(raw, r);
        const std::vector<uint8_t> chunk =
            make_chunk(raw, number++, static_cast<uint32_t>(records.size()));
        file.insert(file.end(), chunk.begin(), chunk.end());
    }
    return file;
}

// A frame loop of three 96 KiB ranges whose floats move a little every frame, two frames per
// chunk (576 KiB: chunks that big are read ahead), the first frame whole, the rest deltas (in
// byte planes and not, alternately), with one rule broken somewhere, as `seed` picks: a wrong
// base, key, layout or size, a lost record, or a second record of a key with other bytes.
std::vector<std::vector<fbs::RecordT>> delta_frames_broken(uint32_t seed) {
    std::mt19937 rng(seed);
    constexpr int kFrames = 8;
    std::vector<std::vector<uint8_t>> last(3);
    std::vector<std::vector<fbs::RecordT>> chunks(kFrames / 2);
    std::vector<std::vector<uint8_t>> all;  // every content, in order
    for (int frame = 0; frame < kFrames; ++frame) {
        for (size_t range = 0; range < last.size(); ++range) {
            std::vector<float> floats(24 * 1024);
            for (size_t i = 0; i < floats.size(); ++i)
                floats[i] = std::sin(0.001f * float(i + 7000 * range)) +
                            (i % 97 == size_t(frame) ? 0.25f * float(frame) : 0.0f);
            std::vector<uint8_t> bytes(floats.size() * 4);
            std::memcpy(bytes.data(), floats.data(), bytes.size());
            chunks[frame / 2].push_back(frame == 0 ? whole_contents(bytes)
                                                   : delta_contents(bytes, last[range],
                                                                    key_of(last[range]),
                                                                    uint8_t(frame % 2 ? 4 : 0)));
            all.push_back(bytes);
            last[range] = std::move(bytes);
        }
    }
    if (seed == 0) return chunks;  // unbroken
    std::vector<fbs::RecordT>& in = chunks[1 + rng() % (chunks.size() - 1)];
    const size_t at = rng() % in.size();
    fbs::MemoryContentsDeltaT* delta = in[at].body.AsMemoryContentsDelta();
    switch (rng() % 6) {
    case 0: delta->base_hash = key_of(all[rng() % all.size()]); break;
    case 1: delta->hash ^= 1; break;
    case 2: delta->byte_planes = delta->byte_planes == 4 ? 0 : (rng() % 2 ? 4 : 7); break;
    case 3: delta->bytes.resize(delta->bytes.size() - 4); break;
    case 4: in.erase(in.begin() + long(at)); break;
    case 5: {  // a whole record of an earlier key holding other bytes
        std::vector<uint8_t> other = all[rng() % all.size()];
        fbs::RecordT dup = whole_contents(other);
        dup.body.AsMemoryContents()->hash = key_of(all[rng() % all.size()]);
        in.insert(in.begin() + long(at), std::move(dup));
        break;
    }
    }
    return chunks;
}

// The contents records' keys and bytes, and the damage, of reading `file` with `options`.
std::string delta_read_summary(const std::vector<uint8_t>& file, TraceReaderOptions options,
                               uint64_t* decoded_ahead) {
    const ReadResult read = read_all_memory(file, options);
    *decoded_ahead += read.stats.deltas_decoded_ahead;
    std::string out = describe(read.damage);
    for (const fbs::RecordT& r : read.records) {
        const auto* whole = r.body.AsMemoryContents();
        const auto* delta = r.body.AsMemoryContentsDelta();
        if (!whole && !delta) continue;
        const std::vector<uint8_t>& bytes = whole ? whole->bytes : delta->bytes;
        out += "\n" + common::hex(whole ? whole->hash : delta->hash, 16) + " " +
               common::hex(key_of(bytes), 16) + " " + std::to_string(bytes.size());
    }
    return out;
}

// Deltas decoded on the read-ahead task are taken only when the caller's thread would decode
// them against the same base: over files that break the delta rules in many ways, with content
// keys checked and not, the records, their bytes and the damage are those of decoding every
// delta on the caller's thread, and both ways were taken.
TEST(TraceDamage, DeltasDecodedAheadReadAsDecodingThemOnTheCallersThread) {
    uint64_t decoded_ahead = 0;
    for (uint32_t seed = 0; seed < 40; ++seed) {
        SCOPED_TRACE(seed);
        const std::vector<uint8_t> file = file_of_chunks(delta_frames_broken(seed));
        for (bool verify : {true, false}) {
            TraceReaderOptions ahead{.verify_content_keys = verify};
            TraceReaderOptions here = ahead;
            here.decode_deltas_ahead = false;
            uint64_t none = 0;
            EXPECT_EQ(delta_read_summary(file, ahead, &decoded_ahead),
                      delta_read_summary(file, here, &none));
            EXPECT_EQ(none, 0u);
        }
        if (seed == 0) {
            EXPECT_EQ(decoded_ahead, 2u * 21u);  // every delta, both times
        }
    }
    // The broken files left some deltas to the caller's thread, and most still decoded ahead.
    EXPECT_LT(decoded_ahead, 40u * 2u * 21u);
    EXPECT_GT(decoded_ahead, 40u * 21u);
}

// What a reader older than 1.7 does with a delta: to it MemoryContentsDelta is a kind it does not
// know (here one past every kind this build knows, crafted the same way). It hands the record
// out as that unknown kind, defines no contents with it, and reports the snapshot naming the
// delta's key as missing contents at that record: never XORed bytes taken for real ones.
TEST(TraceDamage, AReaderThatDoesNotKnowTheKindReportsItsContentsMissing) {
    const std::vector<uint8_t> real(48, 0x21);
    const uint64_t key = f::content_key(real.data(), real.size(), 0, 64);
    const auto unknown = static_cast<fbs::RecordBody>(kRecordKindCount);
    flatbuffers::FlatBufferBuilder b;
    const auto body =
        fbs::CreateMemoryContentsDelta(b, key, 0, 0x1234, b.CreateVector(real), 0).Union();
    fbs::RecordBuilder rb(b);
    rb.add_body_type(unknown);
    rb.add_body(body);
    b.Finish(rb.Finish());
    std::vector<uint8_t> raw;
    frame(raw, b.GetBufferPointer(), b.GetSize(), static_cast<uint32_t>(unknown));
    fbs::CmdCopyBufferT copy;
    copy.inputs.emplace_back(1, 0, 0x1000, real.size(), key);
    fbs::RecordT uses;
    uses.body.Set(std::move(copy));
    frame(raw, uses);
    uint64_t chunk_at = 0;
    std::vector<uint8_t> file = file_of_raw(raw, 2, &chunk_at);

    TraceError e;
    auto reader = TraceReader::open_memory(file.data(), file.size(), "old_reader.clt", &e);
    ASSERT_TRUE(reader) << e.message;
    RecordView v;
    ASSERT_TRUE(reader->next(&v));
    EXPECT_EQ(v.kind, unknown);
    EXPECT_FALSE(contents_record(*v.record));  // no contents a consumer could take
    EXPECT_FALSE(reader->next(&v));            // the copy naming the key is not handed out
    bool missing = false;
    for (const TraceError& d : reader->damage())
        missing |=
            d.code == TraceErrorCode::kMissingContents && d.file_offset == chunk_at &&
            d.message.find("refers to contents " + common::hex(key, 16)) != std::string::npos;
    EXPECT_TRUE(missing) << describe(reader->damage());
    std::vector<uint8_t> got;
    EXPECT_TRUE(reader->read_contents(key, &got));
}

TEST(TraceDamage, UnreadableFileIsAnError) {
    TraceError e;
    EXPECT_FALSE(TraceReader::open("/nonexistent/dir/x.clt", &e));
    EXPECT_EQ(e.code, TraceErrorCode::kIoError);
    EXPECT_EQ(e.message,
              "/nonexistent/dir/x.clt: offset 0: cannot open: No such file or directory");
    EXPECT_FALSE(TraceReader::open("/", &e));
    EXPECT_EQ(e.code, TraceErrorCode::kIoError);
}

}  // namespace
}  // namespace clastrace::traces::testing
