// SPDX-License-Identifier: Apache-2.0
// Damaged files: each kind of damage gets its own error naming the file offset, and
// everything intact around the damage still reads.
#include "trace_test_support.h"

#include "file_format.h"

#include <gtest/gtest.h>

#include <zstd.h>

#include <algorithm>

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

class DamagedTrace : public ::testing::Test {
protected:
    explicit DamagedTrace(int frames = 30) : frames_(frames) {}
    void SetUp() override {
        path_ = temp_path("good.clt");
        written_ = write_frames_trace(path_, frames_, 6000);
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
    fh.version_minor = 9;
    fh.checksum = f::file_header_checksum(fh, file.data() + 32, fh.trace_header_size);
    std::memcpy(file.data(), &fh, sizeof fh);
    TraceError e;
    auto reader = TraceReader::open_memory(file.data(), file.size(), "minor.clt", &e);
    ASSERT_TRUE(reader) << e.message;
    EXPECT_EQ(reader->version_minor(), 9);
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
    std::vector<uint8_t> file = header_only_prefix();
    uint64_t chunk_at = file.size();
    std::vector<uint8_t> chunk = make_chunk(raw, 0, 2);
    file.insert(file.end(), chunk.begin(), chunk.end());
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
    fbs::CommandBufferEndT end;
    fbs::RecordT er;
    er.body.Set(end);
    frame(raw, er);
    std::vector<uint8_t> file = header_only_prefix();
    uint64_t chunk_at = file.size();
    std::vector<uint8_t> chunk = make_chunk(raw, 0, 2);
    file.insert(file.end(), chunk.begin(), chunk.end());
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
            fbs::CommandBufferEndT end;
            fbs::RecordT er;
            er.body.Set(end);
            frame(raw, er);
            std::vector<uint8_t> file = header_only_prefix();
            const uint64_t chunk_at = file.size();
            std::vector<uint8_t> chunk = make_chunk(raw, 0, 3);
            file.insert(file.end(), chunk.begin(), chunk.end());
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
    std::vector<uint8_t> file = header_only_prefix();
    std::vector<uint8_t> chunk = make_chunk(raw, 0, 1);
    file.insert(file.end(), chunk.begin(), chunk.end());
    ReadResult read = read_all_memory(file);
    EXPECT_TRUE(has_damage(read, TraceErrorCode::kContentMismatch)) << describe(read.damage);
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

TEST(TraceDamage, RecordFailingTheVerifierIsSkippedAndTheNextOneRead) {
    std::vector<uint8_t> raw;
    std::vector<uint8_t> junk(24, 0xff);  // root offset points far outside
    frame(raw, junk.data(), junk.size(), 3);
    fbs::CommandBufferEndT end;
    fbs::RecordT er;
    er.body.Set(end);
    frame(raw, er);
    std::vector<uint8_t> file = header_only_prefix();
    uint64_t chunk_at = file.size();
    std::vector<uint8_t> chunk = make_chunk(raw, 0, 2);
    file.insert(file.end(), chunk.begin(), chunk.end());
    ReadResult read = read_all_memory(file);
    ASSERT_TRUE(has_damage(read, TraceErrorCode::kInvalidRecord, chunk_at))
        << describe(read.damage);
    EXPECT_NE(describe(read.damage).find("fails the FlatBuffers verifier"), std::string::npos);
    ASSERT_EQ(read.records.size(), 1u);
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
