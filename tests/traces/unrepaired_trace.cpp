// SPDX-License-Identifier: Apache-2.0
#include "unrepaired_trace.h"

#include "file_format.h"

#include <zstd.h>

#include <cstring>
#include <fstream>
#include <stdexcept>

namespace clastrace::traces::testing {

namespace {

namespace f = format;

struct FileBytes {
    std::vector<uint8_t> bytes;

    void append(const void* data, size_t size) {
        const auto* p = static_cast<const uint8_t*>(data);
        bytes.insert(bytes.end(), p, p + size);
    }
    void pad8() { bytes.resize(f::align8(bytes.size()), 0); }

    // One chunk (header and zstd payload) at the end; returns its compressed size.
    uint32_t append_chunk(const std::vector<uint8_t>& raw, f::ChunkKind kind, uint32_t number,
                          uint32_t records, uint64_t first_submission) {
        std::vector<uint8_t> compressed(ZSTD_compressBound(raw.size()));
        const size_t n =
            ZSTD_compress(compressed.data(), compressed.size(), raw.data(), raw.size(), 3);
        if (ZSTD_isError(n)) throw std::runtime_error("zstd failed");
        const f::ChunkHeader h =
            f::sealed_chunk_header(kind, number, records, first_submission,
                                   static_cast<uint32_t>(raw.size()), compressed.data(),
                                   static_cast<uint32_t>(n));
        append(&h, sizeof h);
        append(compressed.data(), n);
        return static_cast<uint32_t>(n);
    }
};

// The records chunk being filled.
struct OpenChunk {
    std::vector<uint8_t> raw;
    uint32_t records = 0, submissions = 0;
    uint64_t first_submission = 0;
};

}  // namespace

void write_unrepaired_trace(const std::string& path, const fbs::TraceHeaderT& header,
                            const std::vector<fbs::RecordT>& records) {
    FileBytes file;
    flatbuffers::FlatBufferBuilder hb;
    hb.Finish(fbs::TraceHeader::Pack(hb, &header));
    f::FileHeader fh{};
    std::memcpy(fh.magic, f::kFileMagic, sizeof fh.magic);
    fh.version_major = f::kVersionMajor;
    fh.version_minor = f::kVersionMinor;
    fh.trace_header_size = hb.GetSize();
    fh.checksum = f::file_header_checksum(fh, hb.GetBufferPointer(), hb.GetSize());
    file.append(&fh, sizeof fh);
    file.append(hb.GetBufferPointer(), hb.GetSize());
    file.pad8();

    const uint32_t chunk_limit = header.capture && header.capture->chunk_raw_bytes
                                     ? header.capture->chunk_raw_bytes
                                     : 4u << 20;
    std::vector<fbs::ChunkLocation> chunks;
    std::vector<fbs::ContentLocation> contents;
    uint64_t submissions = 0;
    OpenChunk open;
    auto seal = [&] {
        if (open.raw.empty()) return;
        const uint64_t offset = file.bytes.size();
        const uint32_t csize = file.append_chunk(open.raw, f::ChunkKind::kRecords,
                                                 static_cast<uint32_t>(chunks.size()), open.records,
                                                 open.first_submission);
        chunks.emplace_back(offset, open.first_submission, open.submissions, open.records,
                            static_cast<uint32_t>(open.raw.size()), csize);
        open = OpenChunk{{}, 0, 0, submissions};
    };
    for (const fbs::RecordT& record : records) {
        flatbuffers::FlatBufferBuilder b;
        b.Finish(fbs::Record::Pack(b, &record));
        const size_t framed = f::kRecordFrameSize + f::align8(b.GetSize());
        if (!open.raw.empty() && open.raw.size() + framed > chunk_limit) seal();
        if (const fbs::MemoryContentsT* c = record.body.AsMemoryContents()) {
            contents.emplace_back(c->hash, c->bytes.size(), static_cast<uint32_t>(chunks.size()),
                                  static_cast<uint32_t>(open.raw.size()));
        }
        const uint32_t frame[2] = {b.GetSize(), static_cast<uint32_t>(record.body.type)};
        const size_t at = open.raw.size();
        open.raw.resize(at + framed, 0);
        std::memcpy(open.raw.data() + at, frame, sizeof frame);
        std::memcpy(open.raw.data() + at + f::kRecordFrameSize, b.GetBufferPointer(), b.GetSize());
        ++open.records;
        if (record.body.type == fbs::RecordBody::QueueSubmit) {
            ++open.submissions;
            ++submissions;
        }
    }
    seal();

    flatbuffers::FlatBufferBuilder ib;
    ib.Finish(fbs::CreateTraceIndex(ib, ib.CreateVectorOfStructs(chunks),
                                    ib.CreateVectorOfStructs(contents), records.size(),
                                    submissions));
    const std::vector<uint8_t> index(ib.GetBufferPointer(), ib.GetBufferPointer() + ib.GetSize());
    const uint64_t index_offset = file.bytes.size();
    const uint32_t index_size =
        file.append_chunk(index, f::ChunkKind::kIndex, static_cast<uint32_t>(chunks.size()), 0,
                          submissions);
    const f::Trailer t =
        f::sealed_trailer(index_offset, index_offset + f::kChunkHeaderSize + index_size);
    file.append(&t, sizeof t);

    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(file.bytes.data()),
              static_cast<std::streamsize>(file.bytes.size()));
    if (!out) throw std::runtime_error("cannot write " + path);
}

}  // namespace clastrace::traces::testing
