// SPDX-License-Identifier: Apache-2.0
// Streams payloads (chunk_streams.h, issue 23): a records chunk stored as the records with the
// contents' bytes cut out and those bytes (whole contents in byte planes) in two zstd frames
// decodes to the very raw bytes one frame holds; damage is reported with the file and offset.
#include "records_chunks.h"
#include "trace_test_support.h"

#include "byte_planes.h"
#include "chunk_streams.h"
#include "file_format.h"

#include <clastrace/traces/records.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <random>

namespace clastrace::traces::testing {
namespace {

namespace f = format;

std::vector<uint8_t> compress(const std::vector<uint8_t>& raw) {
    std::vector<uint8_t> out(ZSTD_compressBound(raw.size()));
    out.resize(ZSTD_compress(out.data(), out.size(), raw.data(), raw.size(), 3));
    return out;
}

std::vector<uint8_t> encode(const std::vector<uint8_t>& raw, std::span<const f::ContentCut> cuts) {
    ZSTD_CCtx* cctx = ZSTD_createCCtx();
    std::vector<uint8_t> payload;
    EXPECT_EQ(f::encode_streams_payload(cctx, raw.data(), raw.size(), cuts, 3, 0, &payload), "");
    ZSTD_freeCCtx(cctx);
    return payload;
}

f::StreamsProblem decode(const std::vector<uint8_t>& payload, std::vector<uint8_t>* out) {
    ZSTD_DCtx* dctx = ZSTD_createDCtx();
    const f::StreamsProblem p =
        f::decode_streams_payload(dctx, payload.data(), payload.size(), out->data(), out->size());
    ZSTD_freeDCtx(dctx);
    return p;
}

// A streams payload assembled from a records stream as given (cut table included) and a
// contents stream: what a damaged or crafted writer could produce.
std::vector<uint8_t> assemble(const std::vector<uint8_t>& records,
                              const std::vector<uint8_t>& contents) {
    const std::vector<uint8_t> r = compress(records), c = compress(contents);
    std::vector<uint8_t> payload(f::kStreamsHeaderSize);
    const uint32_t header[4] = {f::kStreamsMagic, uint32_t(r.size()), uint32_t(c.size()), 0};
    std::memcpy(payload.data(), header, sizeof header);
    payload.insert(payload.end(), r.begin(), r.end());
    payload.insert(payload.end(), c.begin(), c.end());
    return payload;
}

TEST(ContentStreams, EncodeThenDecodeGivesTheRawBytesBack) {
    std::mt19937 rng(7);
    std::vector<uint8_t> raw(10007);
    for (uint8_t& b : raw) b = uint8_t(rng());
    // Cuts at the very start and end, back to back, empty, with tails of 1 to 3 bytes.
    const std::vector<f::ContentCut> cuts = {{0, 64, f::CutLayout::kBytePlanes},
                                             {64, 13, f::CutLayout::kAsIs},
                                             {100, 0, f::CutLayout::kBytePlanes},
                                             {100, 4001, f::CutLayout::kBytePlanes},
                                             {5000, 2, f::CutLayout::kBytePlanes},
                                             {6000, 999, f::CutLayout::kAsIs},
                                             {9000, 1007, f::CutLayout::kBytePlanes}};
    for (size_t n : {size_t{0}, cuts.size()}) {
        const std::vector<uint8_t> payload = encode(raw, std::span(cuts).first(n));
        ASSERT_TRUE(f::is_streams_payload(payload.data(), payload.size()));
        std::vector<uint8_t> back(raw.size(), 0xee);
        const f::StreamsProblem p = decode(payload, &back);
        EXPECT_EQ(p.what, "") << n << " cuts";
        EXPECT_TRUE(back == raw) << n << " cuts";
    }
}

// Whole float contents in planes: the contents stream holds byte 0 of every word first.
// The writer builds a chunk already split (records with the cuts left out, the cuts' bytes in
// their layout): joining it gives the raw bytes back, and its payload is the one the raw bytes
// encode to.
TEST(ContentStreams, ASplitChunkJoinsToItsRawBytesAndEncodesAsThem) {
    std::mt19937 rng(11);
    std::vector<uint8_t> raw(5003);
    for (uint8_t& b : raw) b = uint8_t(rng() % 7);
    const std::vector<f::ContentCut> cuts = {{16, 37, f::CutLayout::kBytePlanes},
                                             {53, 0, f::CutLayout::kAsIs},
                                             {80, 1000, f::CutLayout::kAsIs},
                                             {1100, 3001, f::CutLayout::kBytePlanes},
                                             {4990, 13, f::CutLayout::kBytePlanes}};
    f::UninitializedBytes records, contents;
    size_t from = 0;
    for (const f::ContentCut& c : cuts) {
        records.insert(records.end(), raw.begin() + long(from), raw.begin() + long(c.offset));
        const size_t at = contents.size();
        contents.resize(at + c.size);
        if (c.layout == f::CutLayout::kBytePlanes)
            f::to_byte_planes(raw.data() + c.offset, c.size, contents.data() + at);
        else
            std::memcpy(contents.data() + at, raw.data() + c.offset, c.size);
        from = c.offset + c.size;
    }
    records.insert(records.end(), raw.begin() + long(from), raw.end());
    const f::SplitChunk split{records, contents, cuts};
    ASSERT_EQ(split.raw_size(), raw.size());

    f::UninitializedBytes joined;
    f::join_split_chunk(split, &joined);
    EXPECT_TRUE(std::equal(joined.begin(), joined.end(), raw.begin(), raw.end()));

    ZSTD_CCtx* cctx = ZSTD_createCCtx();
    f::UninitializedBytes payload;
    EXPECT_EQ(f::encode_split_chunk(cctx, split, 3, 0, &payload), "");
    ZSTD_freeCCtx(cctx);
    const std::vector<uint8_t> from_raw = encode(raw, cuts);
    EXPECT_TRUE(std::equal(payload.begin(), payload.end(), from_raw.begin(), from_raw.end()));
    std::vector<uint8_t> back(raw.size());
    EXPECT_FALSE(decode({payload.begin(), payload.end()}, &back));
    EXPECT_EQ(back, raw);
}

TEST(ContentStreams, WholeContentsGoInBytePlanes) {
    std::vector<uint8_t> raw(64);
    for (size_t i = 0; i < raw.size(); ++i) raw[i] = uint8_t(i);
    const f::ContentCut cut{8, 16, f::CutLayout::kBytePlanes};
    const std::vector<uint8_t> payload = encode(raw, std::span(&cut, 1));
    uint32_t records_frame;
    std::memcpy(&records_frame, payload.data() + 4, 4);
    std::vector<uint8_t> contents(16);
    ASSERT_EQ(ZSTD_decompress(contents.data(), contents.size(),
                              payload.data() + f::kStreamsHeaderSize + records_frame,
                              payload.size() - f::kStreamsHeaderSize - records_frame),
              16u);
    const std::vector<uint8_t> planes = {8,  12, 16, 20, 9,  13, 17, 21,
                                         10, 14, 18, 22, 11, 15, 19, 23};
    EXPECT_EQ(contents, planes);
}

// Byte planes are for 32-bit integers; floats keep their repeats whole, zeros need no planes.
TEST(ContentStreams, PlanesAreChosenForIntegerContentsOnly) {
    std::vector<uint32_t> indices(3000);
    for (size_t i = 0; i < indices.size(); ++i) indices[i] = uint32_t(i * 7919 % 20000);
    std::vector<float> vertices(3000);
    for (size_t i = 0; i < vertices.size(); ++i) vertices[i] = std::sin(float(i)) * 50.f;
    std::vector<uint32_t> room(3000, 0);
    room[5] = 1;
    auto pays = [](const auto& v) {
        return f::planes_pay(reinterpret_cast<const uint8_t*>(v.data()), v.size() * 4);
    };
    EXPECT_TRUE(pays(indices));
    EXPECT_FALSE(pays(vertices));
    EXPECT_FALSE(pays(room));
    EXPECT_FALSE(pays(std::vector<uint32_t>(15, 3)));  // too short to judge
    EXPECT_TRUE(pays(std::vector<uint32_t>(16, 3)));
}

// A trace whose contents are whole (vertices, indices, odd sizes) and deltas.
std::map<uint64_t, std::vector<uint8_t>> write_contents_trace(const std::string& path,
                                                              TraceWriterOptions options) {
    std::map<uint64_t, std::vector<uint8_t>> bytes_by_key;
    options.chunk_raw_bytes = 16384;
    TraceError e;
    auto w = TraceWriter::create(path, test_header(), options, &e);
    EXPECT_TRUE(w) << e.message;
    if (!w) return bytes_by_key;
    std::vector<float> vertices(900);
    for (size_t i = 0; i < vertices.size(); ++i) vertices[i] = std::cos(0.01f * float(i)) * 40.f;
    std::vector<uint32_t> indices(600);
    for (size_t i = 0; i < indices.size(); ++i) indices[i] = uint32_t(i * 7 % 301);
    std::vector<uint8_t> odd(1001);
    for (size_t i = 0; i < odd.size(); ++i) odd[i] = uint8_t(i * i);
    for (int frame = 0; frame < 12; ++frame) {
        vertices[size_t(frame) * 31 % vertices.size()] += 1.f;
        odd[size_t(frame)] ^= 0x40;
        append_build_snapshotting(*w,
                                  {{1, vertices.data(), vertices.size() * 4},
                                   {2, indices.data(), indices.size() * 4},
                                   {3 + uint64_t(frame), odd.data(), odd.size()},
                                   {4, odd.data(), 3}},
                                  bytes_by_key);
    }
    EXPECT_FALSE(w->finish());
    return bytes_by_key;
}

// The raw bytes of every records chunk, whatever its payload.
std::vector<std::vector<uint8_t>> raw_chunks(const std::vector<uint8_t>& file) {
    std::vector<std::vector<uint8_t>> raws;
    for (const ChunkAt& c : records_chunks(file)) {
        const uint8_t* payload = file.data() + c.offset + f::kChunkHeaderSize;
        std::vector<uint8_t> raw(c.header.raw_size);
        if (f::is_streams_payload(payload, c.header.compressed_size)) {
            EXPECT_FALSE(decode({payload, payload + c.header.compressed_size}, &raw));
        } else {
            EXPECT_EQ(ZSTD_decompress(raw.data(), raw.size(), payload, c.header.compressed_size),
                      raw.size());
        }
        raws.push_back(std::move(raw));
    }
    return raws;
}

TEST(ContentStreams, ChunksDecodeToTheBytesOfOneFrameAndEveryContentReadsBack) {
    const std::string streams_path = temp_path("streams_on.clt");
    const std::string one_frame_path = temp_path("streams_off.clt");
    const auto written = write_contents_trace(streams_path, {});
    TraceWriterOptions off;
    off.content_streams = false;
    EXPECT_EQ(write_contents_trace(one_frame_path, off), written);

    const std::vector<uint8_t> streams = read_file(streams_path);
    const std::vector<uint8_t> one_frame = read_file(one_frame_path);
    const std::vector<ChunkAt> chunks = records_chunks(streams);
    ASSERT_GE(chunks.size(), 3u);
    for (const ChunkAt& c : chunks)
        EXPECT_TRUE(f::is_streams_payload(streams.data() + c.offset + f::kChunkHeaderSize,
                                          c.header.compressed_size));
    EXPECT_TRUE(raw_chunks(streams) == raw_chunks(one_frame));

    ReadResult read = read_all(streams_path);  // content keys verified
    ASSERT_EQ(read.damage_count, 0u) << describe(read.damage);
    size_t contents = 0, deltas = 0;
    for (const fbs::RecordT& r : read.records) {
        std::vector<uint8_t> bytes;
        uint64_t hash = 0;
        if (const auto* whole = r.body.AsMemoryContents()) {
            hash = whole->hash;
            bytes = whole->bytes;
        } else if (const auto* delta = r.body.AsMemoryContentsDelta()) {
            hash = delta->hash;
            bytes = delta->bytes;  // the reader hands out the real bytes
            ++deltas;
        } else {
            continue;
        }
        ++contents;
        EXPECT_EQ(bytes, written.at(hash));
    }
    EXPECT_EQ(contents, written.size());
    EXPECT_GT(deltas, 10u);
    // read_contents out of scan order, through the index.
    TraceError e;
    auto reader = TraceReader::open(streams_path, &e);
    ASSERT_TRUE(reader) << e.message;
    for (auto it = written.rbegin(); it != written.rend(); ++it) {
        std::vector<uint8_t> bytes;
        ASSERT_FALSE(reader->read_contents(it->first, &bytes));
        EXPECT_EQ(bytes, it->second);
    }
}

// 40 frames of 64 tiny random contents (1 to 8 bytes) at zstd's fastest level (its literals
// stored as they are), in chunks of 64 KiB.
std::map<uint64_t, std::vector<uint8_t>> write_tiny_contents_trace(const std::string& path,
                                                                   TraceWriterOptions options) {
    std::map<uint64_t, std::vector<uint8_t>> bytes_by_key;
    options.zstd_level = ZSTD_minCLevel();
    options.chunk_raw_bytes = 64u << 10;
    TraceError e;
    auto w = TraceWriter::create(path, test_header(), options, &e);
    EXPECT_TRUE(w) << e.message;
    if (!w) return bytes_by_key;
    std::mt19937 rng(5);
    std::vector<std::vector<uint8_t>> bytes(64);
    for (uint64_t frame = 0; frame < 40; ++frame) {
        std::vector<SnapshotPiece> pieces;
        for (size_t i = 0; i < bytes.size(); ++i) {
            bytes[i].resize(1 + rng() % 8);
            for (uint8_t& b : bytes[i]) b = uint8_t(rng());
            pieces.push_back({frame * bytes.size() + i + 1, bytes[i].data(), bytes[i].size()});
        }
        append_build_snapshotting(*w, pieces, bytes_by_key);
    }
    EXPECT_FALSE(w->finish());
    return bytes_by_key;
}

// Tiny contents whose bytes zstd leaves as they are: a streams payload would hold the raw bytes
// and 12 bytes per cut, past ZSTD_compressBound of the raw size, the limit readers put on a
// payload. The writer stores those chunks as one frame, whose raw bytes are those content_streams
// off writes, and the trace reads back byte for byte, through the scan and through the index.
TEST(ContentStreams, ChunksWhoseStreamsWouldPassTheBoundAreOneFrameAndReadBack) {
    const std::string path = temp_path("past_the_bound.clt");
    const std::string off_path = temp_path("past_the_bound_off.clt");
    const auto written = write_tiny_contents_trace(path, {});
    TraceWriterOptions off;
    off.content_streams = false;
    ASSERT_EQ(write_tiny_contents_trace(off_path, off), written);

    const std::vector<uint8_t> file = read_file(path);
    size_t one_frame = 0;
    for (const ChunkAt& c : records_chunks(file)) {
        EXPECT_LE(c.header.compressed_size, ZSTD_compressBound(c.header.raw_size));
        one_frame += !f::is_streams_payload(file.data() + c.offset + f::kChunkHeaderSize,
                                            c.header.compressed_size);
    }
    EXPECT_EQ(one_frame, records_chunks(file).size());  // every chunk holds contents
    EXPECT_GE(one_frame, 3u);
    EXPECT_TRUE(raw_chunks(file) == raw_chunks(read_file(off_path)));

    const ReadResult read = read_all(path);  // content keys verified
    ASSERT_EQ(read.damage_count, 0u) << describe(read.damage);
    size_t contents = 0;
    for (const fbs::RecordT& r : read.records) {
        if (const auto* whole = r.body.AsMemoryContents()) {
            EXPECT_EQ(whole->bytes, written.at(whole->hash));
            ++contents;
        } else if (const auto* delta = r.body.AsMemoryContentsDelta()) {
            EXPECT_EQ(delta->bytes, written.at(delta->hash));
            ++contents;
        }
    }
    EXPECT_EQ(contents, written.size());
    TraceError e;
    auto reader = TraceReader::open(path, &e);
    ASSERT_TRUE(reader) << e.message;
    for (auto it = written.rbegin(); it != written.rend(); ++it) {
        std::vector<uint8_t> got;
        ASSERT_FALSE(reader->read_contents(it->first, &got));
        EXPECT_EQ(got, it->second);
    }
}

// A file that says it is format 1.7 cannot hold streams payloads: such a chunk is damage (a
// crafted or mislabelled file), named with the version, not decoded.
TEST(ContentStreams, AStreamsPayloadInAnOlderMinorIsDamage) {
    const std::string path = temp_path("streams_minor7.clt");
    write_contents_trace(path, {});
    std::vector<uint8_t> file = read_file(path);
    f::FileHeader fh;
    std::memcpy(&fh, file.data(), sizeof fh);
    fh.version_minor = f::kFirstStreamsMinor - 1;
    fh.checksum = f::file_header_checksum(fh, file.data() + sizeof fh, fh.trace_header_size);
    std::memcpy(file.data(), &fh, sizeof fh);
    const std::string older = temp_path("streams_minor7_2.clt");
    write_file(older, file);

    ReadResult read = read_all(older);
    ASSERT_EQ(read.damage.size(), records_chunks(file).size()) << describe(read.damage);
    for (const TraceError& e : read.damage) {
        EXPECT_EQ(e.code, TraceErrorCode::kDecompressFailed);
        EXPECT_NE(e.message.find("is a streams payload, which format 1.7"), std::string::npos)
            << e.message;
    }
}

// Damage inside a streams payload whose checksum was made to hold: the chunk is reported with
// the file, the byte where the problem lies and what is wrong; the other chunks still read.
TEST(ContentStreams, ADamagedStreamsPayloadNamesFileAndOffset) {
    const std::string path = temp_path("streams_damaged.clt");
    write_contents_trace(path, {});
    std::vector<uint8_t> file = read_file(path);
    const ChunkAt c = records_chunks(file)[1];
    const uint64_t payload = c.offset + f::kChunkHeaderSize;
    // One byte moves from the records frame's size to the contents frame's: the sum holds.
    uint32_t sizes[2];
    std::memcpy(sizes, file.data() + payload + 4, 8);
    sizes[0] += 1;
    sizes[1] -= 1;
    std::memcpy(file.data() + payload + 4, sizes, 8);
    f::ChunkHeader h = c.header;
    h.payload_checksum = f::checksum(file.data() + payload, h.compressed_size);
    h.header_checksum = f::chunk_header_checksum(h);
    std::memcpy(file.data() + c.offset, &h, sizeof h);
    const std::string damaged = temp_path("streams_damaged_2.clt");
    write_file(damaged, file);

    ReadResult read = read_all(damaged);
    ASSERT_GE(read.damage.size(), 1u);
    const TraceError& first = read.damage.front();
    EXPECT_EQ(first.code, TraceErrorCode::kDecompressFailed) << first.message;
    EXPECT_EQ(first.message.rfind(damaged + ": offset ", 0), 0u) << first.message;
    EXPECT_EQ(first.file_offset, payload + f::kStreamsHeaderSize) << first.message;
    EXPECT_NE(first.message.find("chunk 1 streams payload: the records stream does not "
                                 "decompress"),
              std::string::npos)
        << first.message;
    EXPECT_GT(read.records.size(), 0u);  // chunks 0 and 2 on still read
}

TEST(ContentStreams, CraftedCutTablesAreRefusedWithTheReason) {
    std::vector<uint8_t> out(100);
    auto table = [](std::vector<uint32_t> words, size_t records_bytes) {
        std::vector<uint8_t> bytes(words.size() * 4 + records_bytes, 0x11);
        if (!words.empty())  // data() of an empty vector may be null, which memcpy may not take
            std::memcpy(bytes.data(), words.data(), words.size() * 4);
        return bytes;
    };
    const std::vector<uint8_t> contents(50, 0x22);
    struct Case {
        std::vector<uint8_t> records;
        const char* says;
    };
    const Case cases[] = {
        {table({1, 10, 50, 7}, 50), "cut 0 has layout 7, which this reader does not know"},
        {table({1, 60, 50, 0}, 50), "cut 0 skips 60 record bytes, past the end"},
        {table({1, 10, 95, 0}, 50), "cut 0 of 95 bytes at raw byte 10 runs past"},
        {table({9, 10, 50, 0}, 50), "9 cuts do not fit"},
        {table({1, 10, 40, 0}, 50), "for a chunk of 100"},
        {table({}, 0), "no cut count"},
    };
    for (const Case& c : cases) {
        const f::StreamsProblem p = decode(assemble(c.records, contents), &out);
        EXPECT_NE(p.what.find(c.says), std::string::npos) << p.what;
        EXPECT_EQ(p.at, f::kStreamsHeaderSize);
    }
    EXPECT_FALSE(decode(assemble(table({1, 10, 50, 4}, 50), contents), &out)) << "the valid one";
    const std::vector<uint8_t> short_contents(49, 0x22);
    const f::StreamsProblem p = decode(assemble(table({1, 10, 50, 0}, 50), short_contents), &out);
    EXPECT_NE(p.what.find("does not declare the cuts' 50 bytes"), std::string::npos) << p.what;
    EXPECT_GT(p.at, f::kStreamsHeaderSize);

    std::vector<uint8_t> payload = assemble(table({1, 10, 50, 0}, 50), contents);
    payload[12] = 1;
    EXPECT_EQ(decode(payload, &out).at, 12u);
    payload[12] = 0;
    payload.pop_back();
    EXPECT_NE(decode(payload, &out).what.find("do not fill the payload"), std::string::npos);
}

}  // namespace
}  // namespace clastrace::traces::testing
