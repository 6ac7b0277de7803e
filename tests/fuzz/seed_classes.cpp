// SPDX-License-Identifier: Apache-2.0
// Writes the seed classes the shipped traces lack into a folder, for the fuzz targets:
//   utf8-*.clt  intact traces whose strings are not UTF-8 (Latin-1 device, application and
//               engine names; ray-check, debug and timestamp labels; capture findings),
//               and every given sample with its header strings made Latin-1;
//   read-ahead-deltas.clt  delta contents in chunks big enough to be read ahead;
//   bomb-*.clt  chunks whose small zstd payload decompresses to 256 MiB of zeros (or claims
//               a size its frame exceeds), and index chunks of 1 GiB raw size.
// Made in code, not checked in, so they follow the format as it changes.
//   fuzz_seed_classes OUT_DIR [SAMPLE.clt...]
#include "../traces/trace_test_support.h"
#include "chunk_streams.h"
#include "file_format.h"

#include <clastrace/traces/records.h>

#include <zstd.h>

#include <cstdio>
#include <cstring>
#include <filesystem>
#include <functional>
#include <map>
#include <string>
#include <vector>

namespace f = clastrace::traces::format;
using namespace clastrace;
using Bytes = std::vector<uint8_t>;

namespace {

[[noreturn]] void fail(const std::string& why) {
    std::fprintf(stderr, "fuzz_seed_classes: %s\n", why.c_str());
    std::exit(1);
}

// Ill-formed UTF-8 of every kind a reader meets: Latin-1 letters, a lone continuation byte,
// an overlong '/', a UTF-16 surrogate, a sequence cut short, bytes UTF-8 never uses.
const std::vector<std::string> kIllFormed = {"\xe9",         "\x80",     "\xc0\xaf",
                                             "\xed\xa0\x80", "\xe2\x82", "\xff\xfe"};

// `text` with ill-formed bytes written over its letters, same length (so FlatBuffers offsets hold).
void make_latin1(char* text, size_t size, size_t variant) {
    size_t at = 0;
    for (size_t k = variant; at < size; ++k) {
        const std::string& bad = kIllFormed[k % kIllFormed.size()];
        if (at + bad.size() > size) break;
        std::memcpy(text + at, bad.data(), bad.size());
        at += bad.size() + 2;  // keep some ASCII between them
    }
}

// Placeholders the writer stores as they are; replaced in the file afterwards, since the
// writer itself may repair what it is given.
std::string placeholder(int n) { return "@@NOT-UTF8-" + std::to_string(10 + n) + "@@"; }

void replace_placeholders(uint8_t* data, size_t size) {
    for (int n = 0; n < 20; ++n) {
        const std::string p = placeholder(n);
        for (uint8_t* at = data;
             (at = static_cast<uint8_t*>(memmem(at, size - (at - data), p.data(), p.size())));) {
            make_latin1(reinterpret_cast<char*>(at), p.size(), size_t(n));
            at += p.size();
        }
    }
}

Bytes compress(const Bytes& raw) {
    Bytes out(ZSTD_compressBound(raw.size()));
    size_t n = ZSTD_compress(out.data(), out.size(), raw.data(), raw.size(), 3);
    if (ZSTD_isError(n)) fail("zstd failed");
    out.resize(n);
    return out;
}

Bytes decompress(const uint8_t* data, size_t size, size_t raw_size) {
    Bytes out(raw_size);
    if (f::is_streams_payload(data, size)) {  // records and contents apart (chunk_streams.h)
        ZSTD_DCtx* dctx = ZSTD_createDCtx();
        const f::StreamsProblem p =
            f::decode_streams_payload(dctx, data, size, out.data(), raw_size);
        ZSTD_freeDCtx(dctx);
        if (p) fail("a chunk of the written trace does not decode: " + p.what);
        return out;
    }
    size_t n = ZSTD_decompress(out.data(), out.size(), data, size);
    if (ZSTD_isError(n) || n != raw_size) fail("a chunk of the written trace does not decompress");
    return out;
}

// A zstd frame of `size` zeros, made a MiB at a time: small on disk, huge when read.
Bytes zeros_frame(uint64_t size) {
    ZSTD_CCtx* c = ZSTD_createCCtx();
    ZSTD_CCtx_setPledgedSrcSize(c, size);
    Bytes zeros(1 << 20, 0), out, buffer(ZSTD_CStreamOutSize());
    for (uint64_t done = 0; done < size;) {
        const size_t n = size_t(std::min<uint64_t>(zeros.size(), size - done));
        done += n;
        ZSTD_inBuffer in{zeros.data(), n, 0};
        const ZSTD_EndDirective mode = done == size ? ZSTD_e_end : ZSTD_e_continue;
        for (size_t left = 1; left != 0 && !(mode == ZSTD_e_continue && in.pos == in.size);) {
            ZSTD_outBuffer o{buffer.data(), buffer.size(), 0};
            left = ZSTD_compressStream2(c, &o, &in, mode);
            if (ZSTD_isError(left)) fail("zstd failed");
            out.insert(out.end(), buffer.data(), buffer.data() + o.pos);
        }
    }
    ZSTD_freeCCtx(c);
    return out;
}

struct Chunk {
    uint64_t offset;
    f::ChunkHeader header;
};

struct Layout {
    uint64_t data_start;
    std::vector<Chunk> chunks;  // records chunks, then the index chunk
};

Layout layout_of(const Bytes& file) {
    Layout l{f::kFileHeaderSize + f::align8(f::load<uint32_t>(file.data() + 12)), {}};
    for (uint64_t at = l.data_start; at + f::kChunkHeaderSize <= file.size() - f::kTrailerSize;) {
        f::ChunkHeader h = f::load<f::ChunkHeader>(file.data() + at);
        if (h.magic != f::kChunkMagic) fail("no chunk where one must be");
        l.chunks.push_back({at, h});
        at += f::kChunkHeaderSize + h.compressed_size;
    }
    if (l.chunks.empty() || l.chunks.back().header.kind != uint16_t(f::ChunkKind::kIndex))
        fail("no index chunk");
    return l;
}

void append_chunk(Bytes& out, f::ChunkHeader h, const Bytes& payload) {
    h.compressed_size = uint32_t(payload.size());
    h.payload_checksum = f::checksum(payload.data(), payload.size());
    h.header_checksum = f::chunk_header_checksum(h);
    const auto* p = reinterpret_cast<const uint8_t*>(&h);
    out.insert(out.end(), p, p + sizeof h);
    out.insert(out.end(), payload.begin(), payload.end());
}

void append_trailer(Bytes& out, uint64_t index_offset) {
    f::Trailer t{};
    std::memcpy(t.magic, f::kTrailerMagic, sizeof t.magic);
    t.index_offset = index_offset;
    t.trailer_offset = out.size();
    t.checksum = f::trailer_checksum(t);
    const auto* p = reinterpret_cast<const uint8_t*>(&t);
    out.insert(out.end(), p, p + sizeof t);
}

void reseal_file_header(Bytes& file) {
    f::FileHeader h = f::load<f::FileHeader>(file.data());
    h.checksum = f::file_header_checksum(h, file.data() + f::kFileHeaderSize, h.trace_header_size);
    std::memcpy(file.data(), &h, sizeof h);
}

// The file with `patch` applied to the raw bytes of every records chunk (same length) and
// to the index (given the chunks' new sizes). Chunks move; the index is rewritten to match.
Bytes rewrite_chunks(
    const Bytes& file, const std::function<void(Bytes&)>& patch_records,
    const std::function<Bytes(const Bytes& raw, uint32_t* raw_size)>& index_payload) {
    const Layout l = layout_of(file);
    Bytes out(file.begin(), file.begin() + l.data_start);
    std::vector<std::pair<Chunk, Chunk>> moved;  // old, new
    for (const Chunk& c : l.chunks) {
        Bytes raw = decompress(file.data() + c.offset + f::kChunkHeaderSize,
                               c.header.compressed_size, c.header.raw_size);
        Chunk now{out.size(), c.header};
        if (c.header.kind == uint16_t(f::ChunkKind::kRecords)) {
            patch_records(raw);
        } else {
            // ChunkLocation {file_offset u64, first_submission u64, 4 x u32 ..., compressed_size u32 at +28}.
            for (const auto& [was, is] : moved) {
                for (size_t at = 0; at + 32 <= raw.size(); at += 8) {
                    if (f::load<uint64_t>(raw.data() + at) == was.offset &&
                        f::load<uint32_t>(raw.data() + at + 28) == was.header.compressed_size) {
                        std::memcpy(raw.data() + at, &is.offset, 8);
                        std::memcpy(raw.data() + at + 28, &is.header.compressed_size, 4);
                    }
                }
            }
            Bytes payload = index_payload(raw, &now.header.raw_size);
            append_chunk(out, now.header, payload);
            append_trailer(out, now.offset);
            return out;
        }
        Bytes payload = compress(raw);
        now.header.raw_size = uint32_t(raw.size());
        now.header.compressed_size = uint32_t(payload.size());
        append_chunk(out, now.header, payload);
        moved.push_back({c, now});
    }
    return out;
}

Bytes compress_index(const Bytes& raw, uint32_t*) { return compress(raw); }

void save_seed(const std::filesystem::path& dir, const std::string& name, const Bytes& bytes) {
    clastrace::traces::testing::write_file((dir / name).string(), bytes);
}

void check_intact(const Bytes& file, const std::string& name) {
    traces::TraceError e;
    auto reader =
        traces::TraceReader::open_memory(file.data(), file.size(), name, &e,
                                         traces::TraceReaderOptions{.verify_content_keys = true});
    if (!reader) fail(name + " does not open: " + e.message);
    traces::RecordView v;
    while (reader->next(&v)) {}
    if (reader->damage_count()) fail(name + " is damaged: " + reader->damage().front().message);
}

// One record of every kind with placeholders for its strings, written by the TraceWriter.
Bytes written_with_placeholders(const std::filesystem::path& dir) {
    const std::string path = (dir / "placeholders.clt.tmp").string();
    fbs::TraceHeaderT header = traces::testing::test_header();
    header.device->name = placeholder(0);
    header.device->driver_info = placeholder(1);
    header.capture->application_name = placeholder(2);
    header.capture->engine_name = placeholder(3);
    header.capture->capture_tool = placeholder(4);
    traces::TraceError e;
    traces::TraceWriterOptions options;
    options.sync_on_finish = false;
    auto writer = traces::TraceWriter::create(path, header, options, &e);
    if (!writer) fail(e.message);
    int n = 5;
    for (fbs::RecordT& r : traces::testing::one_of_every_kind(*writer)) {
        if (auto* t = r.body.AsCpuTimestamp()) t->label = placeholder(n++);
        if (auto* t = r.body.AsDebugLabel()) t->text = placeholder(n++);
        if (auto* t = r.body.AsRayQueryCheck()) t->label = placeholder(n++);
        if (auto* t = r.body.AsCaptureFinding()) {
            t->rule = placeholder(n++);
            t->message = placeholder(n++);
        }
        if (traces::TraceError a = writer->append(r)) fail(a.message);
    }
    if (traces::TraceError a = writer->finish()) fail(a.message);
    writer.reset();
    Bytes file = traces::testing::read_file(path);
    std::filesystem::remove(path);
    return file;
}

// Frames whose vertices change a little (delta contents) in records chunks above 256 KiB:
// every chunk after the first is read ahead, its deltas XORed on the read-ahead thread from
// bases it keeps or reads whole from the chunks it may read (the samples' chunks lead it to the
// index chunk only). Zeros, mostly: a few KiB of file.
Bytes read_ahead_deltas(const std::filesystem::path& dir) {
    const std::string path = (dir / "read-ahead.clt.tmp").string();
    traces::TraceWriterOptions options;
    options.sync_on_finish = false;
    options.chunk_raw_bytes = 400u << 10;  // 4 or 5 frames of 80 KB
    traces::TraceError e;
    auto writer = traces::TraceWriter::create(path, traces::testing::test_header(), options, &e);
    if (!writer) fail(e.message);
    std::vector<float> vertices(20000);
    for (size_t i = 0; i < vertices.size(); ++i) vertices[i] = float(i % 97);
    std::map<uint64_t, Bytes> bytes_by_key;
    for (size_t frame = 0; frame < 24; ++frame) {
        for (size_t k = 0; k < 6; ++k) vertices[(frame * 37 + k * 11) % vertices.size()] += 0.5f;
        traces::testing::append_build_snapshotting(*writer,
                                                   {{1, vertices.data(), vertices.size() * 4}},
                                                   bytes_by_key);
    }
    if (traces::TraceError a = writer->finish()) fail(a.message);
    writer.reset();
    Bytes file = traces::testing::read_file(path);
    std::filesystem::remove(path);
    return file;
}

// The sample with every string of its header made ill-formed, same lengths.
Bytes with_latin1_header(Bytes file) {
    const uint32_t size = f::load<uint32_t>(file.data() + 12);
    if (f::kFileHeaderSize + uint64_t(size) > file.size()) fail("sample header too short");
    const auto* h = flatbuffers::GetRoot<fbs::TraceHeader>(
        file.data() + f::kFileHeaderSize);  // bytes of our own copy
    size_t variant = 0;
    auto spoil = [&](const flatbuffers::String* s) {
        if (s) make_latin1(const_cast<char*>(s->c_str()), s->size(), variant++);
    };
    if (h->device()) {
        spoil(h->device()->name());
        spoil(h->device()->driver_info());
    }
    if (h->capture()) {
        spoil(h->capture()->application_name());
        spoil(h->capture()->engine_name());
    }
    reseal_file_header(file);
    return file;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc < 2) fail("usage: fuzz_seed_classes OUT_DIR [SAMPLE.clt...]");
    const std::filesystem::path dir = argv[1];
    std::filesystem::create_directories(dir);

    const Bytes base = written_with_placeholders(dir);
    check_intact(base, "the placeholder trace");
    Bytes utf8 = rewrite_chunks(
        base, [](Bytes& raw) { replace_placeholders(raw.data(), raw.size()); }, compress_index);
    replace_placeholders(utf8.data(), layout_of(utf8).data_start);
    reseal_file_header(utf8);
    check_intact(utf8, "utf8-every-kind.clt");
    save_seed(dir, "utf8-every-kind.clt", utf8);
    for (int i = 2; i < argc; ++i) {
        const Bytes sample = with_latin1_header(traces::testing::read_file(argv[i]));
        check_intact(sample, argv[i]);
        save_seed(dir, "utf8-" + std::filesystem::path(argv[i]).filename().string(), sample);
    }

    const Bytes ahead = read_ahead_deltas(dir);
    check_intact(ahead, "read-ahead-deltas.clt");
    save_seed(dir, "read-ahead-deltas.clt", ahead);

    const Bytes zeros_256m = zeros_frame(uint64_t(f::kMaxChunkRawBytes));
    const Layout l = layout_of(base);
    const Bytes prefix(base.begin(), base.begin() + l.data_start);
    f::ChunkHeader records{};
    records.magic = f::kChunkMagic;
    records.kind = uint16_t(f::ChunkKind::kRecords);
    records.record_count = 1;
    records.raw_size = f::kMaxChunkRawBytes;
    Bytes bomb = prefix;
    append_chunk(bomb, records, zeros_256m);
    save_seed(dir, "bomb-records-256MiB-of-zeros.clt", bomb);
    records.raw_size = 4096;  // the frame holds far more than the header claims
    bomb = prefix;
    append_chunk(bomb, records, zeros_256m);
    save_seed(dir, "bomb-records-frame-exceeds-raw-size.clt", bomb);

    const Bytes zeros_1g = zeros_frame(uint64_t(f::kMaxIndexRawBytes));
    save_seed(dir, "bomb-index-1GiB-of-zeros.clt",
              rewrite_chunks(
                  base, [](Bytes&) {},
                  [&](const Bytes&, uint32_t* raw_size) {
                      *raw_size = f::kMaxIndexRawBytes;
                      return zeros_1g;
                  }));
    // The intact index payload under a header claiming 1 GiB: checked before allocating?
    Bytes claim = base;
    const Chunk& index = l.chunks.back();
    f::ChunkHeader h = index.header;
    h.raw_size = f::kMaxIndexRawBytes;
    h.header_checksum = f::chunk_header_checksum(h);
    std::memcpy(claim.data() + index.offset, &h, sizeof h);
    save_seed(dir, "bomb-index-claims-1GiB.clt", claim);
    std::printf("fuzz_seed_classes: seeds written to %s\n", dir.c_str());
    return 0;
}
