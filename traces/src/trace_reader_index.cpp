// SPDX-License-Identifier: Apache-2.0
// The index: read and checked on open, and each chunk the scan reads checked against it.
#include "trace_reader_impl.h"

#include <algorithm>
#include <string>

namespace clastrace::traces {

using namespace reader;

uint64_t TraceReader::Impl::plausible_index_raw_bytes() const {
    uint64_t plausible = kIndexFixedBytes +
                         kIndexBytesPerChunk * (size / format::kChunkHeaderSize) +
                         kIndexBytesPerContent * (size / 8);
    return std::min<uint64_t>(plausible, format::kMaxIndexRawBytes);
}

void TraceReader::Impl::check_chunk_against_index(uint64_t at, const format::ChunkHeader& h) {
    if (!index) return;
    auto it = index_position.find(at);
    if (it == index_position.end()) {
        report(TraceErrorCode::kBadIndex, at,
               "chunk " + std::to_string(h.chunk_number) +
                   " is a records chunk the index does not list");
        return;
    }
    CLASTRACE_DEBUG_ASSERT(it->second < index_chunk_read.size());
    const fbs::ChunkLocation* c = index->chunks()->Get(it->second);
    index_chunk_read[it->second] = true;
    std::string differs;
    auto compare = [&](const char* field, uint64_t listed, uint64_t read) {
        if (listed != read) {
            differs += std::string(differs.empty() ? "" : ", ") + field + " " +
                       std::to_string(listed) + " in the index, " + std::to_string(read) +
                       " in the chunk";
        }
    };
    compare("chunk number", it->second, h.chunk_number);
    compare("first submission", c->first_submission(), h.first_submission);
    compare("record count", c->record_count(), h.record_count);
    compare("raw size", c->raw_size(), h.raw_size);
    compare("compressed size", c->compressed_size(), h.compressed_size);
    if (!differs.empty()) {
        report(TraceErrorCode::kBadIndex, at,
               "index entry " + std::to_string(it->second) +
                   " disagrees with the chunk there: " + differs);
    }
}

void TraceReader::Impl::check_submissions_against_index() {
    if (!index) return;
    auto it = index_position.find(chunk_offset);
    if (it == index_position.end()) return;
    uint32_t listed = index->chunks()->Get(it->second)->submission_count();
    if (listed != chunk_submissions) {
        report(TraceErrorCode::kBadIndex, chunk_offset,
               "index entry " + std::to_string(it->second) + " says chunk " +
                   std::to_string(chunk.chunk_number) + " holds " + std::to_string(listed) +
                   " submissions, it holds " + std::to_string(chunk_submissions));
    }
}

void TraceReader::Impl::finish_scan() {
    if (!index || !full_scan || budget_exhausted) return;
    full_scan = false;  // once per scan
    const auto* chunks = index->chunks();
    for (uint32_t i = 0; i < chunks->size(); ++i) {
        if (index_chunk_read[i] || repeats_an_offset(i))
            continue;  // a repeat: the index is bad_index from open
        report_with(TraceErrorCode::kBadIndex, chunks->Get(i)->file_offset(), [&] {
            return "index entry " + std::to_string(i) + " lists a records chunk at offset " +
                   std::to_string(chunks->Get(i)->file_offset()) +
                   " that the scan did not read as one";
        });
    }
    if (damage_total != 0) return;
    if (index->record_count() != scan_records_claimed ||
        index->submission_count() != next_submission) {
        report(TraceErrorCode::kBadIndex, index_offset,
               "index counts " + std::to_string(index->record_count()) + " records and " +
                   std::to_string(index->submission_count()) + " submissions, the chunks hold " +
                   std::to_string(scan_records_claimed) + " and " +
                   std::to_string(next_submission));
    }
}

void TraceReader::Impl::open_index() {
    if (size < data_start + format::kTrailerSize) {
        report(TraceErrorCode::kTruncated, size,
               "no trailer: the file was cut or its writer never finished");
        return;
    }
    const uint64_t trailer_at = size - format::kTrailerSize;
    format::Trailer t{};
    if (!src->read_at(trailer_at, sizeof t, reinterpret_cast<uint8_t*>(&t))) return;
    if (std::memcmp(t.magic, format::kTrailerMagic, 8) != 0) {
        report(TraceErrorCode::kTruncated, size,
               "no trailer at the end of the file: it was cut or its writer never finished");
        return;
    }
    uint64_t computed = format::trailer_checksum(t);
    if (computed != t.checksum) {
        report(TraceErrorCode::kBadIndex, trailer_at,
               "trailer checksum mismatch (stored " + hex(t.checksum) + ", computed " +
                   hex(computed) + ")");
        return;
    }
    if (t.trailer_offset != trailer_at || t.index_offset < data_start ||
        t.index_offset > trailer_at - std::min<uint64_t>(trailer_at, format::kChunkHeaderSize)) {
        report(TraceErrorCode::kBadIndex, trailer_at, "trailer points outside the file");
        return;
    }
    format::ChunkHeader h{};
    TraceError err;
    if (read_chunk(t.index_offset, &h, &index_raw, &err) != ChunkStatus::kOk) {
        err.code = err.code == TraceErrorCode::kTruncated ? TraceErrorCode::kBadIndex : err.code;
        err.message += " (index chunk)";
        report(std::move(err));
        return;
    }
    if (h.kind != static_cast<uint16_t>(format::ChunkKind::kIndex) ||
        t.index_offset + format::kChunkHeaderSize + h.compressed_size != trailer_at) {
        report(TraceErrorCode::kBadIndex, t.index_offset,
               "trailer does not point at the index chunk");
        return;
    }
    flatbuffers::Verifier verifier(index_raw.data(), index_raw.size(), 64, 10'000'000);
    if (!verifier.VerifyBuffer<fbs::TraceIndex>(nullptr)) {
        report(TraceErrorCode::kBadIndex, t.index_offset, "index fails the FlatBuffers verifier");
        return;
    }
    const auto* idx = flatbuffers::GetRoot<fbs::TraceIndex>(index_raw.data());
    if (!idx->chunks()) {
        report(TraceErrorCode::kBadIndex, t.index_offset, "index lists no chunks");
        return;
    }
    // The index chunk's own header must agree with what it indexes.
    if (h.record_count != 0 || h.first_submission != idx->submission_count() ||
        h.chunk_number != idx->chunks()->size()) {
        report(TraceErrorCode::kBadIndex, t.index_offset,
               "index chunk header disagrees with the index (record count " +
                   std::to_string(h.record_count) + ", first submission " +
                   std::to_string(h.first_submission) + ", chunk number " +
                   std::to_string(h.chunk_number) + ")");
        return;
    }
    index = idx;
    index_offset = t.index_offset;
    check_index_entries();
    if (const auto* places = index->contents()) {
        const auto* chunks = index->chunks();
        contents.reserve(places->size());
        bool reported = false;
        for (const fbs::ContentLocation* c : *places) {
            if (c->chunk() >= chunks->size()) {
                if (!reported) {
                    report(TraceErrorCode::kBadIndex, index_offset,
                           "index places contents " + hex(c->hash()) + " in chunk " +
                               std::to_string(c->chunk()) + ", it lists " +
                               std::to_string(chunks->size()) + " chunks");
                }
                reported = true;
                continue;
            }
            contents.emplace(c->hash(),
                             ContentPlace{c->size(), chunks->Get(c->chunk())->file_offset(),
                                          c->raw_offset(), false});
        }
    }
    CLASTRACE_DEBUG_ASSERT(chunk_index_holds());
}

void TraceReader::Impl::check_index_entries() {
    const auto* chunks = index->chunks();
    index_position.reserve(chunks->size());
    index_chunk_read.assign(chunks->size(), false);
    uint64_t records = 0;
    uint64_t submissions = 0;
    uint64_t previous_end = data_start;
    std::string problem;
    for (uint32_t i = 0; i < chunks->size(); ++i) {
        const fbs::ChunkLocation* c = chunks->Get(i);
        // The first entry for an offset is the one kept (emplace), so the scan checks the chunk
        // there against it, and the repeat is named as what it is.
        const auto [first, fresh] = index_position.emplace(c->file_offset(), i);
        if (problem.empty() && !fresh) {
            problem = "entries " + std::to_string(first->second) + " and " + std::to_string(i) +
                      " both place a chunk at offset " + std::to_string(c->file_offset()) +
                      " (entry " + std::to_string(first->second) + " is kept)";
        }
        if (problem.empty() &&
            (c->file_offset() < previous_end || c->file_offset() >= index_offset)) {
            problem = "entry " + std::to_string(i) + " places a chunk at offset " +
                      std::to_string(c->file_offset()) + ", outside the records after offset " +
                      std::to_string(previous_end);
        }
        if (problem.empty() && c->first_submission() != submissions) {
            problem = "entry " + std::to_string(i) + " starts at submission " +
                      std::to_string(c->first_submission()) + " after " +
                      std::to_string(submissions) + " submissions";
        }
        previous_end = c->file_offset() + format::kChunkHeaderSize + c->compressed_size();
        records += c->record_count();
        submissions += c->submission_count();
    }
    if (problem.empty() &&
        (records != index->record_count() || submissions != index->submission_count())) {
        problem = "its chunks hold " + std::to_string(records) + " records and " +
                  std::to_string(submissions) + " submissions, its totals say " +
                  std::to_string(index->record_count()) + " and " +
                  std::to_string(index->submission_count());
    }
    if (!problem.empty()) report(TraceErrorCode::kBadIndex, index_offset, "index: " + problem);
}

bool TraceReader::Impl::repeats_an_offset(uint32_t entry) const {
    return index_position.at(index->chunks()->Get(entry)->file_offset()) != entry;
}

bool TraceReader::Impl::chunk_index_holds() const {
    const auto* chunks = index->chunks();
    if (index_chunk_read.size() != chunks->size() || index_position.size() > chunks->size())
        return false;
    for (const auto& [offset, place] : index_position)
        if (place >= chunks->size() || chunks->Get(place)->file_offset() != offset) return false;
    for (const auto& [hash, place] : contents)
        if (!place.seen_in_scan && !index_position.contains(place.chunk_offset)) return false;
    return true;
}

}  // namespace clastrace::traces
