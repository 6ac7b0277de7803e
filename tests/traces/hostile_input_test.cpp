// SPDX-License-Identifier: Apache-2.0
// Hostile traces: files crafted so that reading them would cost minutes of CPU or
// gigabytes of memory, or would hide damage behind a consistent-looking index. Each
// gets bounded work (asserted on counts, never on time) and one verdict: damage.
#include "records_chunks.h"
#include "shell_run.h"
#include "trace_test_support.h"
#include "unrepaired_trace.h"

#include "file_format.h"

#include <gtest/gtest.h>

#include <zstd.h>

#include <algorithm>
#include <functional>

namespace clastrace::traces::testing {
namespace {

namespace f = clastrace::traces::format;

// Builds a finished trace chunk by chunk: a writer-made file header, crafted chunks, and
// an index and trailer that list exactly those chunks, so only what a test breaks is wrong.
class CraftedTrace {
public:
    CraftedTrace() {
        const std::string path = temp_path("hostile_prefix.clt");
        TraceError e;
        auto w = TraceWriter::create(path, test_header(), {}, &e);
        EXPECT_TRUE(w) << e.message;
        EXPECT_FALSE(w->finish());
        file_ = read_file(path);
        file_.resize(f::kFileHeaderSize + f::align8(f::load<uint32_t>(file_.data() + 12)));
    }

    // A records chunk holding `records` (framed as the writer frames them); its offset.
    uint64_t add_records(const std::vector<fbs::RecordT>& records) {
        std::vector<uint8_t> raw;
        uint32_t submissions = 0;
        for (const fbs::RecordT& r : records) {
            if (const auto* c = r.body.AsMemoryContents()) {
                index_.contents.emplace_back(c->hash, c->bytes.size(),
                                             static_cast<uint32_t>(index_.chunks.size()),
                                             static_cast<uint32_t>(raw.size()));
            }
            if (r.body.type == fbs::RecordBody::QueueSubmit) ++submissions;
            flatbuffers::FlatBufferBuilder b;
            b.Finish(fbs::Record::Pack(b, &r));
            frame(raw, b.GetBufferPointer(), b.GetSize(), static_cast<uint32_t>(r.body.type));
        }
        return add_raw(raw, static_cast<uint32_t>(records.size()), submissions);
    }

    // A records chunk of any raw bytes (zeros, broken frames) claiming `records` records.
    uint64_t add_raw(const std::vector<uint8_t>& raw, uint32_t records, uint32_t submissions = 0) {
        return add_payload(compress(raw), static_cast<uint32_t>(raw.size()), records, submissions);
    }

    // A records chunk whose payload is `payload` as it stands (no frame, a frame of nothing),
    // claiming `raw_size` raw bytes and `records` records.
    uint64_t add_payload(const std::vector<uint8_t>& payload, uint32_t raw_size, uint32_t records,
                         uint32_t submissions = 0) {
        const uint64_t at = file_.size();
        const f::ChunkHeader h =
            append_payload_to(file_, payload, raw_size, f::ChunkKind::kRecords, records,
                              submissions_, static_cast<uint32_t>(index_.chunks.size()));
        index_.chunks.emplace_back(at, submissions_, submissions, records, h.raw_size,
                                   h.compressed_size);
        index_.record_count += records;
        submissions_ += submissions;
        index_.submission_count = submissions_;
        return at;
    }

    // Index chunk and trailer; `edit` may change the index first.
    std::vector<uint8_t> finish(const std::function<void(fbs::TraceIndexT&)>& edit = {}) {
        fbs::TraceIndexT index = index_;
        if (edit) edit(index);
        flatbuffers::FlatBufferBuilder b;
        b.Finish(fbs::TraceIndex::Pack(b, &index));
        std::vector<uint8_t> raw(b.GetBufferPointer(), b.GetBufferPointer() + b.GetSize());
        std::vector<uint8_t> file = file_;
        const uint64_t index_at = file.size();
        append_chunk_to(file, raw, f::ChunkKind::kIndex, 0, index.submission_count,
                        static_cast<uint32_t>(index.chunks.size()));
        append_trailer(file, index_at);
        return file;
    }

    const std::vector<uint8_t>& file() const { return file_; }

    static void frame(std::vector<uint8_t>& raw, const uint8_t* data, size_t size, uint32_t kind) {
        uint32_t head[2] = {static_cast<uint32_t>(size), kind};
        size_t at = raw.size();
        raw.resize(at + 8 + f::align8(size), 0);
        std::memcpy(raw.data() + at, head, 8);
        std::memcpy(raw.data() + at + 8, data, size);
    }

    static std::vector<uint8_t> compress(const std::vector<uint8_t>& raw) {
        std::vector<uint8_t> compressed(ZSTD_compressBound(raw.size()));
        size_t n = ZSTD_compress(compressed.data(), compressed.size(), raw.data(), raw.size(), 1);
        compressed.resize(n);
        return compressed;
    }

    static f::ChunkHeader append_chunk_to(std::vector<uint8_t>& file,
                                          const std::vector<uint8_t>& raw, f::ChunkKind kind,
                                          uint32_t records, uint64_t first_submission,
                                          uint32_t number) {
        return append_payload_to(file, compress(raw), static_cast<uint32_t>(raw.size()), kind,
                                 records, first_submission, number);
    }

    static f::ChunkHeader append_payload_to(std::vector<uint8_t>& file,
                                            const std::vector<uint8_t>& payload, uint32_t raw_size,
                                            f::ChunkKind kind, uint32_t records,
                                            uint64_t first_submission, uint32_t number) {
        const f::ChunkHeader h =
            f::sealed_chunk_header(kind, number, records, first_submission, raw_size,
                                   payload.data(), static_cast<uint32_t>(payload.size()));
        const size_t at = file.size();
        file.resize(at + sizeof h);
        std::memcpy(file.data() + at, &h, sizeof h);
        file.insert(file.end(), payload.begin(), payload.end());
        return h;
    }

    static void append_trailer(std::vector<uint8_t>& file, uint64_t index_at) {
        const f::Trailer t = f::sealed_trailer(index_at, file.size());
        const size_t at = file.size();
        file.resize(at + sizeof t);
        std::memcpy(file.data() + at, &t, sizeof t);
    }

private:
    std::vector<uint8_t> file_;
    fbs::TraceIndexT index_;
    uint64_t submissions_ = 0;
};

fbs::RecordT submit(uint64_t index) {
    fbs::QueueSubmitT q;
    q.submission_index = index;
    q.queue = 7;
    fbs::RecordT r;
    r.body.Set(std::move(q));
    return r;
}

fbs::RecordT contents(std::vector<uint8_t> bytes, bool honest_key = true) {
    fbs::MemoryContentsT c;
    c.hash = f::content_key(bytes.data(), bytes.size(), 0, 64) ^ (honest_key ? 0 : 1);
    c.bytes = std::move(bytes);
    fbs::RecordT r;
    r.body.Set(std::move(c));
    return r;
}

// Two submissions per chunk, three chunks: the shape the tests below break.
CraftedTrace three_chunks() {
    CraftedTrace t;
    for (uint64_t s = 0; s < 6; s += 2) t.add_records({submit(s), submit(s + 1)});
    return t;
}

// The chunk header at `at` changed by `edit`, its checksum sealed again.
void edit_chunk_header(std::vector<uint8_t>& file, uint64_t at,
                       const std::function<void(f::ChunkHeader&)>& edit) {
    f::ChunkHeader h;
    std::memcpy(&h, file.data() + at, sizeof h);
    edit(h);
    h.header_checksum = f::chunk_header_checksum(h);
    std::memcpy(file.data() + at, &h, sizeof h);
}

struct Read {
    uint64_t records = 0;
    uint64_t submissions = 0;
    std::vector<uint64_t> submission_indices;
    std::vector<TraceError> damage;
    uint64_t damage_count = 0;
    TraceReadStats stats;
};

Read read(const std::vector<uint8_t>& file,
          TraceReaderOptions options = {.verify_content_keys = true}) {
    Read out;
    TraceError e;
    auto reader = TraceReader::open_memory(file.data(), file.size(), "hostile.clt", &e, options);
    EXPECT_TRUE(reader) << e.message;
    if (!reader) return out;
    RecordView v;
    while (reader->next(&v)) {
        ++out.records;
        if (v.kind == fbs::RecordBody::QueueSubmit) {
            out.submission_indices.push_back(v.record->body_as_QueueSubmit()->submission_index());
        }
    }
    out.submissions = out.submission_indices.size();
    out.damage = reader->damage();
    out.damage_count = reader->damage_count();
    out.stats = reader->stats();
    return out;
}

const TraceError* find_damage(const Read& r, TraceErrorCode code, const std::string& text = {}) {
    auto it = std::find_if(r.damage.begin(), r.damage.end(), [&](const TraceError& e) {
        return e.code == code && e.message.find(text) != std::string::npos;
    });
    return it == r.damage.end() ? nullptr : &*it;
}

TEST(HostileTrace, CraftedTraceIsIntact) {
    Read r = read(three_chunks().finish());
    EXPECT_EQ(r.damage_count, 0u) << describe(r.damage);
    EXPECT_EQ(r.submissions, 6u);
}

TEST(HostileTrace, DefaultBudgetIsThousandTwentyFourTimesTheFileWithAFloor) {
    EXPECT_EQ(default_raw_budget(1000), kRawBudgetFloorBytes);
    EXPECT_EQ(default_raw_budget(uint64_t{100} << 20), uint64_t{102400} << 20);
    EXPECT_EQ(default_raw_budget(UINT64_MAX), UINT64_MAX);
}

TEST(HostileTrace, ZeroBombChunksStopAtTheDecompressionBudget) {
    CraftedTrace t;
    const std::vector<uint8_t> zeros(8u << 20, 0);
    std::vector<uint64_t> offsets;
    for (int i = 0; i < 16; ++i) offsets.push_back(t.add_raw(zeros, 1));
    std::vector<uint8_t> file = t.finish();
    ASSERT_LT(file.size(), 64u << 10);  // 128 MiB of zeros in a few KiB

    TraceReaderOptions options{.verify_content_keys = true, .max_raw_bytes = 20u << 20};
    Read r = read(file, options);
    EXPECT_LE(r.stats.raw_bytes_decompressed, options.max_raw_bytes);
    EXPECT_EQ(r.stats.raw_budget, options.max_raw_bytes);
    // Chunks 0 and 1 fit, chunk 2 would pass 20 MiB: reading stops there, said once.
    const TraceError* over = find_damage(r, TraceErrorCode::kLengthOutOfRange, "past the budget");
    ASSERT_NE(over, nullptr) << describe(r.damage);
    EXPECT_EQ(over->file_offset, offsets[2]);
    EXPECT_NE(over->message.find("chunk 2 would inflate"), std::string::npos) << over->message;
    EXPECT_NE(over->message.find("--max-raw-mib"), std::string::npos) << over->message;
    EXPECT_LE(r.damage_count, 12u) << describe(r.damage);
}

TEST(HostileTrace, ChunkOfZerosCostsAFewProblemsNotOnePerFrame) {
    CraftedTrace t;
    const uint64_t zero_chunk = t.add_raw(std::vector<uint8_t>(1u << 20, 0), 1);
    t.add_records({submit(0)});
    Read r = read(t.finish());
    // 131072 frames of size 0 would each fail the verifier: the chunk stops after a few.
    EXPECT_LE(r.damage_count, 8u) << describe(r.damage);
    EXPECT_LE(r.stats.records_damaged, 8u);
    const TraceError* stop = find_damage(r, TraceErrorCode::kInvalidRecord, "broken record frames");
    ASSERT_NE(stop, nullptr) << describe(r.damage);
    EXPECT_EQ(stop->file_offset, zero_chunk);
    EXPECT_NE(stop->message.find("raw bytes of the chunk are skipped"), std::string::npos)
        << stop->message;
    EXPECT_EQ(r.submissions, 1u);  // the chunk after it still reads
}

TEST(HostileTrace, ZeroBombSeekedToAgainIsNotDecompressedAgain) {
    CraftedTrace t;
    const std::vector<uint8_t> zeros(4u << 20, 0);
    t.add_raw(zeros, 1, 1);  // claims submission 0, holds nothing but empty frames
    t.add_records({submit(1)});
    const std::vector<uint8_t> file = t.finish();
    TraceError e;
    auto reader = TraceReader::open_memory(file.data(), file.size(), "hostile.clt", &e);
    ASSERT_TRUE(reader) << e.message;
    std::vector<uint64_t> decompressed{reader->stats().raw_bytes_decompressed};
    std::vector<uint64_t> damage{reader->damage_count()};
    for (int seek = 0; seek < 3; ++seek) {
        EXPECT_EQ(reader->seek_to_submission(0).code, TraceErrorCode::kInvalidArgument);
        decompressed.push_back(reader->stats().raw_bytes_decompressed);
        damage.push_back(reader->damage_count());
    }
    EXPECT_GE(decompressed[1] - decompressed[0], zeros.size());  // the first seek finds it out
    for (size_t i = 2; i < decompressed.size(); ++i) {
        EXPECT_LT(decompressed[i] - decompressed[i - 1], 1024u) << "seek " << i;
        // The chunk after it, starting past a submission never read, is damage each time.
        EXPECT_EQ(damage[i] - damage[i - 1], damage[2] - damage[1]) << "seek " << i;
    }
    EXPECT_GT(damage[1] - damage[0], damage[2] - damage[1]);  // the broken frames, said once
    const auto& kept = reader->damage();
    EXPECT_EQ(std::count_if(kept.begin(), kept.end(),
                            [](const TraceError& d) {
                                return d.message.find("broken record frames") != std::string::npos;
                            }),
              1);
    EXPECT_FALSE(reader->seek_to_submission(1));  // the chunk after it still reads
}

TEST(HostileTrace, IndexLargerThanTheFileCanNeedIsRefusedBeforeDecompressing) {
    CraftedTrace t = three_chunks();
    std::vector<uint8_t> file = t.file();
    const uint64_t index_at = file.size();
    CraftedTrace::append_chunk_to(file, std::vector<uint8_t>(64, 0), f::ChunkKind::kIndex, 0, 6, 3);
    // Within the format's 1 GiB limit, far past what a small file indexes.
    edit_chunk_header(file, index_at, [](f::ChunkHeader& h) { h.raw_size = 1u << 30; });
    CraftedTrace::append_trailer(file, index_at);
    Read r = read(file);
    const TraceError* e =
        find_damage(r, TraceErrorCode::kLengthOutOfRange, "an index of a file of");
    ASSERT_NE(e, nullptr) << describe(r.damage);
    EXPECT_EQ(e->file_offset, index_at + offsetof(f::ChunkHeader, raw_size));
    EXPECT_LT(r.stats.raw_bytes_decompressed, 1u << 20);
    EXPECT_EQ(r.submissions, 6u);
}

TEST(HostileTrace, RecordsChunkRelabelledAsIndexIsDamageAndLaterChunksStillRead) {
    CraftedTrace t = three_chunks();
    std::vector<uint8_t> file = t.finish();
    // Relabel chunk 1 with a consistent header checksum: as an index chunk, then as a kind the
    // format lacks.
    const uint64_t at = records_chunks(file)[1].offset;
    for (uint16_t kind : {uint16_t{2}, uint16_t{3}}) {
        std::vector<uint8_t> relabelled = file;
        edit_chunk_header(relabelled, at, [&](f::ChunkHeader& h) { h.kind = kind; });
        Read r = read(relabelled);
        EXPECT_EQ(r.submission_indices, (std::vector<uint64_t>{0, 1, 4, 5})) << "kind " << kind;
        EXPECT_NE(find_damage(r, TraceErrorCode::kBadIndex, "that the scan did not read as one"),
                  nullptr)
            << describe(r.damage);
        if (kind == 2) {
            EXPECT_NE(find_damage(r, TraceErrorCode::kBadIndex,
                                  "index chunk here but the trailer points"),
                      nullptr)
                << describe(r.damage);
        } else {
            EXPECT_NE(find_damage(r, TraceErrorCode::kBadChunk,
                                  "has kind 3, which format 1." + std::to_string(f::kVersionMinor) +
                                      " does not define"),
                      nullptr)
                << describe(r.damage);
        }
    }
}

// ChunkLocation is a FlatBuffers struct without setters: a copy with changed fields.
struct Location {
    uint64_t file_offset, first_submission;
    uint32_t submission_count, record_count, raw_size, compressed_size;
};
void edit_location(fbs::ChunkLocation& c, const std::function<void(Location&)>& edit) {
    Location l{c.file_offset(),  c.first_submission(), c.submission_count(),
               c.record_count(), c.raw_size(),         c.compressed_size()};
    edit(l);
    c = fbs::ChunkLocation(l.file_offset, l.first_submission, l.submission_count, l.record_count,
                           l.raw_size, l.compressed_size);
}

TEST(HostileTrace, IndexDisagreeingWithTheChunksIsBadIndex) {
    struct Case {
        const char* name;
        std::function<void(fbs::TraceIndexT&)> edit;
        const char* message;
    };
    const std::vector<Case> cases = {
        {"record count",
         [](fbs::TraceIndexT& i) {
             edit_location(i.chunks[1], [](Location& l) { l.record_count = 3; });
             i.record_count += 1;
         },
         "record count 3 in the index, 2 in the chunk"},
        {"submission count",
         [](fbs::TraceIndexT& i) {
             edit_location(i.chunks[1], [](Location& l) { l.submission_count = 3; });
             edit_location(i.chunks[2], [](Location& l) { l.first_submission = 5; });
             i.submission_count = 7;
         },
         "holds 3 submissions, it holds 2"},
        {"raw size",
         [](fbs::TraceIndexT& i) {
             edit_location(i.chunks[2], [](Location& l) { l.raw_size += 8; });
         },
         "raw size"},
        {"offset",
         [](fbs::TraceIndexT& i) {
             edit_location(i.chunks[2], [](Location& l) { l.file_offset += 8; });
         },
         "is a records chunk the index does not list"},
        {"totals", [](fbs::TraceIndexT& i) { i.record_count += 5; }, "its totals say"},
    };
    for (const Case& c : cases) {
        Read r = read(three_chunks().finish(c.edit));
        EXPECT_NE(find_damage(r, TraceErrorCode::kBadIndex, c.message), nullptr)
            << c.name << "\n"
            << describe(r.damage);
        EXPECT_EQ(r.submissions, 6u) << c.name;
    }
}

TEST(HostileTrace, IndexListingAnOffsetTwiceNamesBothEntriesAndKeepsTheFirst) {
    const std::vector<uint8_t> file = three_chunks().finish([](fbs::TraceIndexT& i) {
        const uint64_t second = i.chunks[1].file_offset();
        edit_location(i.chunks[2], [&](Location& l) { l.file_offset = second; });
    });
    const uint64_t second = records_chunks(file)[1].offset;
    const uint64_t third = records_chunks(file)[2].offset;
    Read r = read(file);
    const TraceError* e = find_damage(r, TraceErrorCode::kBadIndex,
                                      "index: entries 1 and 2 both place a chunk at offset " +
                                          std::to_string(second) + " (entry 1 is kept)");
    ASSERT_NE(e, nullptr) << describe(r.damage);
    EXPECT_EQ(find_damage(r, TraceErrorCode::kBadIndex, "outside the records"), nullptr)
        << describe(r.damage);
    // Entry 1 is the one the chunk there is checked against: it agrees. The third chunk is
    // unlisted; the repeat is not reported again as a chunk the scan missed.
    EXPECT_EQ(find_damage(r, TraceErrorCode::kBadIndex, "disagrees with the chunk"), nullptr)
        << describe(r.damage);
    const TraceError* unlisted = find_damage(r, TraceErrorCode::kBadIndex, "does not list");
    ASSERT_NE(unlisted, nullptr) << describe(r.damage);
    EXPECT_EQ(unlisted->file_offset, third);
    EXPECT_EQ(find_damage(r, TraceErrorCode::kBadIndex, "did not read as one"), nullptr)
        << describe(r.damage);
    EXPECT_EQ(r.submissions, 6u);
}

TEST(HostileTrace, DuplicatedChunkIsSkippedSoNoSubmissionRepeats) {
    CraftedTrace t = three_chunks();
    std::vector<uint8_t> file = t.finish();
    const std::vector<ChunkAt> chunks = records_chunks(file);
    const uint64_t first = chunks[0].offset, second = chunks[1].offset, third = chunks[2].offset;
    // chunk 0, chunk 1, chunk 1 again, chunk 0 again, chunk 2 ...
    std::vector<uint8_t> dup(file.begin(), file.begin() + static_cast<long>(third));
    dup.insert(dup.end(), file.begin() + static_cast<long>(second),
               file.begin() + static_cast<long>(third));
    dup.insert(dup.end(), file.begin() + static_cast<long>(first),
               file.begin() + static_cast<long>(second));
    dup.insert(dup.end(), file.begin() + static_cast<long>(third), file.end());
    Read r = read(dup);
    EXPECT_EQ(r.submission_indices, (std::vector<uint64_t>{0, 1, 2, 3, 4, 5}));
    const TraceError* e = find_damage(r, TraceErrorCode::kBadChunk, "records are skipped");
    ASSERT_NE(e, nullptr) << describe(r.damage);
    EXPECT_EQ(e->file_offset, third);
}

TEST(HostileTrace, DamageBeyondTheKeptListIsCountedCheaply) {
    // 5000 snapshots of undefined contents: each is a problem, only 1000 are kept.
    std::vector<fbs::RecordT> records;
    for (int i = 0; i < 5000; ++i) {
        fbs::CmdCopyBufferT copy;
        copy.inputs.emplace_back(1, 0, 0x1000, 16, 0x1000u + static_cast<uint64_t>(i));
        fbs::RecordT r;
        r.body.Set(std::move(copy));
        records.push_back(std::move(r));
    }
    CraftedTrace t;
    t.add_records(records);
    Read r = read(t.finish());
    EXPECT_EQ(r.damage_count, 5000u);
    EXPECT_EQ(r.damage.size(), 1000u);
}

// ---- Damage the other tests lack: each is named with the file and the offset. ----

// A damaged trace and the one problem it must be reported with (among others it causes).
struct DamageCase {
    std::string name;
    std::vector<uint8_t> file;
    TraceErrorCode code;
    uint64_t offset;
    std::string text;
    std::vector<uint64_t> submissions;  // those still read
};

const std::vector<uint64_t> kAllSix = {0, 1, 2, 3, 4, 5};

// Chunk 1 claims a payload reaching one byte past the end of the file (its raw size raised so
// zstd could make that much): the file is whole (its trailer says so), the header lies, and
// chunk 2 is still read (until session 11 reading stopped there, as at a cut).
DamageCase chunk_one_byte_past_the_end() {
    std::vector<uint8_t> file = three_chunks().finish();
    const ChunkAt c = records_chunks(file)[1];
    const uint64_t remain = file.size() - c.offset - f::kChunkHeaderSize;
    edit_chunk_header(file, c.offset, [&](f::ChunkHeader& h) {
        h.compressed_size = static_cast<uint32_t>(remain + 1);
        h.raw_size = h.compressed_size;
    });
    return {"past_the_end_by_one",
            std::move(file),
            TraceErrorCode::kLengthOutOfRange,
            c.offset + offsetof(f::ChunkHeader, compressed_size),
            "chunk 1 claims " + std::to_string(remain + 1) + " compressed bytes but only " +
                std::to_string(remain) + " remain in the file, which its trailer says is whole",
            {0, 1, 4, 5}};
}

// The same without index and trailer: the last chunk of a file cut one byte short of it.
DamageCase last_chunk_one_byte_short() {
    const std::vector<uint8_t> whole = three_chunks().finish();
    const ChunkAt c = records_chunks(whole)[2];
    const uint64_t end = c.offset + f::kChunkHeaderSize + c.header.compressed_size;
    std::vector<uint8_t> file(whole.begin(), whole.begin() + static_cast<long>(end - 1));
    return {"last_chunk_one_byte_short",
            std::move(file),
            TraceErrorCode::kTruncated,
            c.offset + offsetof(f::ChunkHeader, compressed_size),
            "chunk 2 claims " + std::to_string(c.header.compressed_size) +
                " compressed bytes but only " + std::to_string(c.header.compressed_size - 1) +
                " remain in the file",
            {0, 1, 2, 3}};
}

// Chunk 1's payload is empty (no zstd frame at all) under a header claiming 96 raw bytes.
DamageCase empty_payload() {
    CraftedTrace t;
    t.add_records({submit(0), submit(1)});
    const uint64_t at = t.add_payload({}, 96, 2, 2);
    t.add_records({submit(4), submit(5)});
    return {"empty_payload",
            t.finish(),
            TraceErrorCode::kDecompressFailed,
            at + f::kChunkHeaderSize,
            "chunk 1 zstd frame does not declare the chunk's 96 raw bytes",
            {0, 1, 4, 5}};
}

// Chunk 1 is a zstd frame of nothing, under a header claiming 2 records.
DamageCase empty_frame() {
    CraftedTrace t;
    t.add_records({submit(0), submit(1)});
    const uint64_t at = t.add_payload(CraftedTrace::compress({}), 0, 2, 2);
    t.add_records({submit(4), submit(5)});
    return {"empty_frame",
            t.finish(),
            TraceErrorCode::kInvalidRecord,
            at,
            "chunk 1 header says 2 records, its payload holds 0",
            {0, 1, 4, 5}};
}

// The index lists chunk 1 before chunk 0 (their offsets swapped): offsets that go back.
DamageCase index_offsets_going_back() {
    CraftedTrace t = three_chunks();
    const uint64_t index_at = t.file().size();
    std::vector<uint8_t> file = t.finish([](fbs::TraceIndexT& i) {
        const uint64_t first = i.chunks[0].file_offset();
        const uint64_t second = i.chunks[1].file_offset();
        edit_location(i.chunks[0], [&](Location& l) { l.file_offset = second; });
        edit_location(i.chunks[1], [&](Location& l) { l.file_offset = first; });
    });
    const uint64_t first = records_chunks(file)[0].offset;
    return {"index_offsets_going_back",
            std::move(file),
            TraceErrorCode::kBadIndex,
            index_at,
            "index: entry 1 places a chunk at offset " + std::to_string(first) +
                ", outside the records after offset",
            kAllSix};
}

// The index (and its chunk's header, which must agree) lists a fourth chunk, where the index
// itself lies.
DamageCase index_listing_a_chunk_too_many() {
    CraftedTrace t = three_chunks();
    const uint64_t index_at = t.file().size();
    std::vector<uint8_t> file = t.finish([&](fbs::TraceIndexT& i) {
        i.chunks.emplace_back(index_at, 6, 2, 2, 64, 64);
        i.submission_count += 2;
        i.record_count += 2;
    });
    return {"index_listing_a_chunk_too_many",
            std::move(file),
            TraceErrorCode::kBadIndex,
            index_at,
            "index: entry 3 places a chunk at offset " + std::to_string(index_at),
            kAllSix};
}

// The index chunk's header counts 4 chunks, its index lists 3: the index is not used.
DamageCase index_header_claiming_a_chunk_too_many() {
    CraftedTrace t = three_chunks();
    const uint64_t index_at = t.file().size();
    std::vector<uint8_t> file = t.finish();
    edit_chunk_header(file, index_at, [](f::ChunkHeader& h) { h.chunk_number = 4; });
    return {"index_header_claiming_a_chunk_too_many",
            std::move(file),
            TraceErrorCode::kBadIndex,
            index_at,
            "index chunk header disagrees with the index (record count 0, first submission 6, "
            "chunk number 4)",
            kAllSix};
}

std::vector<DamageCase> damage_cases() {
    return {chunk_one_byte_past_the_end(),
            last_chunk_one_byte_short(),
            empty_payload(),
            empty_frame(),
            index_offsets_going_back(),
            index_listing_a_chunk_too_many(),
            index_header_claiming_a_chunk_too_many()};
}

TEST(HostileTrace, DamageTheSamplesLackIsReportedWithFileAndOffset) {
    for (const DamageCase& c : damage_cases()) {
        SCOPED_TRACE(c.name);
        const Read r = read(c.file);
        const TraceError* e = find_damage(r, c.code, c.text);
        ASSERT_NE(e, nullptr) << describe(r.damage);
        EXPECT_EQ(e->file_offset, c.offset) << e->message;
        EXPECT_EQ(e->message.rfind("hostile.clt: offset " + std::to_string(c.offset) + ": ", 0), 0u)
            << e->message;
        EXPECT_EQ(r.submission_indices, c.submissions);
    }
}

// ---- The CLI's verdict: exit 1 from info, replay and analyze. ----

ShellRun run_clastrace(const std::string& args) {
    return run_shell(std::string(CLASTRACE_BIN) + " " + args + " 2>&1");
}

int exit_code(const std::string& args) { return run_clastrace(args).exit_code; }

void expect_damage_verdict(const std::vector<uint8_t>& file, const std::string& name) {
    const std::string path = temp_path(name + ".clt");
    write_file(path, file);
    EXPECT_EQ(exit_code("info " + path), 1) << name;
    EXPECT_EQ(exit_code("replay " + path), 1) << name;
    EXPECT_EQ(exit_code("analyze " + path), 1) << name;
}

TEST(HostileTraceCli, IntactCraftedTraceIsClean) {
    const std::string path = temp_path("crafted_clean.clt");
    CraftedTrace t;
    t.add_records({contents({1, 2, 3, 4}), submit(0)});
    write_file(path, t.finish());
    EXPECT_EQ(exit_code("info " + path), 0);
    EXPECT_EQ(exit_code("replay " + path), 0);
}

TEST(HostileTraceCli, RelabelledChunkIsDamage) {
    std::vector<uint8_t> file = three_chunks().finish();
    edit_chunk_header(file, records_chunks(file)[0].offset, [](f::ChunkHeader& h) { h.kind = 3; });
    expect_damage_verdict(file, "relabelled");
}

TEST(HostileTraceCli, InconsistentIndexIsDamage) {
    expect_damage_verdict(three_chunks().finish([](fbs::TraceIndexT& i) {
        edit_location(i.chunks[0], [](Location& l) { l.raw_size = 1; });
    }),
                          "inconsistent_index");
}

TEST(HostileTraceCli, ContentsFailingTheirKeyAreDamage) {
    CraftedTrace t;
    t.add_records({contents({1, 2, 3, 4}, false), submit(0)});
    expect_damage_verdict(t.finish(), "content_key");
}

TEST(HostileTraceCli, DuplicatedChunkIsDamageNotUnreadable) {
    std::vector<uint8_t> file = three_chunks().finish();
    const std::vector<ChunkAt> chunks = records_chunks(file);
    const uint64_t first = chunks[0].offset, second = chunks[1].offset;
    std::vector<uint8_t> dup(file.begin(), file.begin() + static_cast<long>(second));
    dup.insert(dup.end(), file.begin() + static_cast<long>(first),
               file.begin() + static_cast<long>(second));
    dup.insert(dup.end(), file.begin() + static_cast<long>(second), file.end());
    expect_damage_verdict(dup, "duplicated");
}

// `clastrace info` and `clastrace replay` exit 1 on each, and print the problem with the file
// and the offset.
TEST(HostileTraceCli, DamageTheSamplesLackIsNamedWithFileAndOffset) {
    for (const DamageCase& c : damage_cases()) {
        SCOPED_TRACE(c.name);
        const std::string path = temp_path(c.name + ".clt");
        write_file(path, c.file);
        for (const char* command : {"info", "replay"}) {
            const ShellRun r = run_clastrace(std::string(command) + " " + path);
            EXPECT_EQ(r.exit_code, 1) << command << "\n" << r.output;
            EXPECT_NE(r.output.find(path + ": offset " + std::to_string(c.offset) + ": " + c.text),
                      std::string::npos)
                << command << "\n"
                << r.output;
        }
    }
}

// A captured trace rewritten in 4 KiB chunks, so that its two submissions and the commands
// before each land in different chunks.
std::vector<uint8_t> two_queue_sample_in_small_chunks() {
    TraceError error;
    auto reader = TraceReader::open(CLASTRACE_TWO_QUEUES_SAMPLE, &error);
    EXPECT_NE(reader, nullptr) << error.message;
    if (!reader) return {};
    fbs::TraceHeaderT header;
    reader->header()->UnPackTo(&header);
    header.capture->chunk_raw_bytes = 4096;
    std::vector<fbs::RecordT> records;
    RecordView v;
    while (reader->next(&v)) v.record->UnPackTo(&records.emplace_back());
    const std::string path = temp_path("two_queues_small_chunks.clt");
    write_unrepaired_trace(path, header, records);
    return read_file(path);
}

// The chunk holding submission 0 again after the chunk holding submission 1: handed out, its
// QueueSubmit would take the submissions back, which analyze refuses as unreadable (exit 2).
TEST(HostileTraceCli, CapturedChunkRepeatedAfterALaterSubmissionIsDamageNotUnreadable) {
    std::vector<uint8_t> file = two_queue_sample_in_small_chunks();
    ASSERT_FALSE(file.empty());
    struct Place {
        uint64_t at;
        f::ChunkHeader header;
    };
    std::vector<Place> chunks;
    for (uint64_t at = f::kFileHeaderSize + f::align8(f::load<uint32_t>(file.data() + 12));
         at + f::kChunkHeaderSize <= file.size() &&
         f::load<uint32_t>(file.data() + at) == f::kChunkMagic;) {
        Place p{at, {}};
        std::memcpy(&p.header, file.data() + at, sizeof p.header);
        chunks.push_back(p);
        at += f::kChunkHeaderSize + p.header.compressed_size;
    }
    ASSERT_GE(chunks.size(), 4u);
    const Place& index = chunks.back();
    ASSERT_EQ(index.header.kind, static_cast<uint16_t>(f::ChunkKind::kIndex));
    // The chunk before the first one starting at submission 1 holds QueueSubmit 0.
    auto holding_first = std::find_if(chunks.begin(), chunks.end() - 1, [](const Place& p) {
        return p.header.first_submission == 1;
    });
    ASSERT_NE(holding_first, chunks.begin());
    ASSERT_NE(holding_first, chunks.end() - 1);
    const Place& repeated = *(holding_first - 1);
    const auto repeated_begin = file.begin() + static_cast<long>(repeated.at);
    const auto repeated_end =
        repeated_begin + static_cast<long>(f::kChunkHeaderSize + repeated.header.compressed_size);
    const std::vector<uint8_t> copy(repeated_begin, repeated_end);
    file.insert(file.begin() + static_cast<long>(index.at), copy.begin(), copy.end());
    expect_damage_verdict(file, "repeated_captured_chunk");
}

}  // namespace
}  // namespace clastrace::traces::testing
