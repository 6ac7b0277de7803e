// SPDX-License-Identifier: Apache-2.0
// Records: each frame of the loaded chunk verified and checked against the rules (contents keys,
// snapshots, submission order), next() and seek.
#include "trace_reader_impl.h"

#include <algorithm>
#include <string>

namespace clastrace::traces {

using namespace reader;

std::string TraceReader::Impl::record_place(uint32_t raw_offset) const {
    return "chunk " + std::to_string(chunk.chunk_number) + " record " +
           std::to_string(chunk_records_seen) + " (raw offset " + std::to_string(raw_offset) + ")";
}

RecordStatus TraceReader::Impl::parse_record(RecordView* out) {
    const uint32_t at = static_cast<uint32_t>(cursor);
    const size_t remaining = raw.size() - cursor;
    if (remaining < format::kRecordFrameSize) {
        report_record(TraceErrorCode::kInvalidRecord, at, [&] {
            return ": frame needs 8 bytes, " + std::to_string(remaining) + " remain";
        });
        return RecordStatus::kStopChunk;
    }
    uint32_t rsize = format::load<uint32_t>(raw.data() + cursor);
    uint32_t rkind = format::load<uint32_t>(raw.data() + cursor + 4);
    if (rsize > remaining - format::kRecordFrameSize) {
        report_record(TraceErrorCode::kLengthOutOfRange, at, [&] {
            return ": claims " + std::to_string(rsize) + " bytes, only " +
                   std::to_string(remaining - format::kRecordFrameSize) + " remain in the chunk";
        });
        return RecordStatus::kStopChunk;
    }
    const uint8_t* bytes = raw.data() + cursor + format::kRecordFrameSize;
    cursor =
        std::min<size_t>(raw.size(), cursor + format::kRecordFrameSize + format::align8(rsize));
    ++chunk_records_seen;

    if (!verified_ahead(at)) {
        flatbuffers::Verifier verifier(bytes, rsize, 64, 10'000'000);
        if (!fbs::VerifyRecordBuffer(verifier)) {
            report_record(TraceErrorCode::kInvalidRecord, at,
                          [] { return ": fails the FlatBuffers verifier"; });
            return RecordStatus::kBroken;
        }
    }
    const fbs::Record* record = fbs::GetRecord(bytes);
    fbs::RecordBody kind = record->body_type();
    if (static_cast<uint32_t>(kind) != rkind) {
        report_record(TraceErrorCode::kInvalidRecord, at, [&] {
            return ": frame says kind " + std::to_string(rkind) + ", record holds " +
                   std::to_string(static_cast<unsigned>(kind));
        });
        return RecordStatus::kBroken;
    }
    if (kind == fbs::RecordBody::NONE || record->body() == nullptr) {
        report_record(TraceErrorCode::kInvalidRecord, at, [] { return ": record has no body"; });
        return RecordStatus::kBroken;
    }
    if (!check_record(*record, at)) return RecordStatus::kSkip;

    out->record = record;
    out->kind = kind;
    out->bytes = bytes;
    out->size = rsize;
    out->chunk_offset = chunk_offset;
    out->chunk_number = chunk.chunk_number;
    out->raw_offset = at;
    return RecordStatus::kOk;
}

bool TraceReader::Impl::check_record(const fbs::Record& record, uint32_t at) {
    if (const std::optional<ContentsRecord> c = contents_record(record)) {
        SharedBytes ahead_bytes;  // the task's copy of the real bytes, when it made them
        if (c->delta && !decode_delta(*c, at, &ahead_bytes)) return false;
        if (!c->delta) ahead_bytes = ahead_whole_copy(*c, at);
        const uint8_t* data = c->data();
        size_t n = c->size();
        uint64_t key = options.verify_content_keys
                           ? format::content_key(data, n, c->seed, hash_bits)
                           : c->hash;
        if (key != c->hash) {
            report_record(TraceErrorCode::kContentMismatch, at, [&] {
                return ": contents " + hex(c->hash) + " hold bytes hashing to " + hex(key);
            });
            return false;
        }
        const ContentPlace place{n, chunk_offset, at, true, options.verify_content_keys};
        if (!contents.insert_or_assign(c->hash, place).second) read_back.forget(c->hash);
        if (trace_has_deltas) keep_real_bytes(c->hash, data, n, std::move(ahead_bytes));
        return true;
    }
    SnapshotLists lists = record_snapshots(record);
    bool ok = true;
    for (const SnapshotVector* list : {lists.inputs, lists.outputs}) {
        if (!list) continue;
        for (const fbs::MemorySnapshot* s : *list) {
            auto it = contents.find(s->hash());
            if (it == contents.end() || (!it->second.seen_in_scan && !seeked)) {
                report_record(TraceErrorCode::kMissingContents, at, [&] {
                    return std::string(" (") + record_kind_name(record.body_type()) +
                           "): snapshot of address " + hex(s->address()) + " refers to contents " +
                           hex(s->hash()) + " that no earlier record defines";
                });
                ok = false;
            } else if (it->second.size != s->size()) {
                report_record(TraceErrorCode::kContentMismatch, at, [&] {
                    return std::string(" (") + record_kind_name(record.body_type()) +
                           "): snapshot of address " + hex(s->address()) + " has size " +
                           std::to_string(s->size()) + " but contents " + hex(s->hash()) +
                           " hold " + std::to_string(it->second.size) + " bytes";
                });
                ok = false;
            }
        }
    }
    if (!ok) return false;
    if (const auto* q = record.body_as_QueueSubmit()) {
        if (q->submission_index() != next_submission) {
            report_record(TraceErrorCode::kInvalidRecord, at, [&] {
                return ": submission_index " + std::to_string(q->submission_index()) +
                       ", expected " + std::to_string(next_submission);
            });
        }
        next_submission = q->submission_index() + 1;
        ++chunk_submissions;
    }
    return true;
}

void TraceReader::Impl::close_chunk() {
    decoded_in_raw.clear();
    if (chunk_loaded && !chunk_cut_short && chunk_records_seen != chunk.record_count) {
        report(TraceErrorCode::kInvalidRecord, chunk_offset,
               "chunk " + std::to_string(chunk.chunk_number) + " header says " +
                   std::to_string(chunk.record_count) + " records, its payload holds " +
                   std::to_string(chunk_records_seen));
    }
    if (chunk_loaded && !chunk_cut_short && chunk_records_seen == chunk.record_count) {
        check_submissions_against_index();
    }
    chunk_loaded = false;
    raw_evicted = false;
}

void TraceReader::Impl::stop_chunk_after_broken_frames() {
    report(TraceErrorCode::kInvalidRecord, chunk_offset,
           "chunk " + std::to_string(chunk.chunk_number) + ": " +
               std::to_string(chunk_broken_frames) + " broken record frames; the remaining " +
               std::to_string(raw.size() - cursor) + " raw bytes of the chunk are skipped");
    stats.bytes_skipped += raw.size() - cursor;
    if (chunk_broken_frames == chunk_records_seen) chunks_of_broken_frames.insert(chunk_offset);
    chunk_cut_short = true;
    close_chunk();
}

bool TraceReader::Impl::reload_evicted_chunk() {
    release_side_chunk_if_big();
    format::ChunkHeader h{};
    TraceError err;
    if (read_chunk(chunk_offset, &h, &raw, &err) != ChunkStatus::kOk) {
        report_budget_or(std::move(err));
        chunk_cut_short = true;
        close_chunk();
        return false;
    }
    raw_evicted = false;
    decoded_in_raw.clear();  // fresh bytes: the deltas in them are encoded again
    return true;
}

bool TraceReader::Impl::next(RecordView* out) {
    if (has_pending) {
        *out = pending;
        has_pending = false;
        ++stats.records;
        return true;
    }
    for (;;) {
        if (chunk_loaded && raw_evicted && !reload_evicted_chunk()) continue;
        if (chunk_loaded && cursor < raw.size()) {
            RecordStatus s = parse_record(out);
            if (s == RecordStatus::kOk) {
                ++stats.records;
                return true;
            }
            ++stats.records_damaged;
            if (s == RecordStatus::kBroken && ++chunk_broken_frames >= kMaxBrokenFramesPerChunk) {
                stop_chunk_after_broken_frames();
            } else if (s == RecordStatus::kStopChunk) {
                chunk_cut_short = true;
                close_chunk();
            }
            continue;
        }
        if (chunk_loaded) close_chunk();
        if (ended) return false;
        if (!advance_chunk()) {
            ended = true;
            return false;
        }
    }
}

void TraceReader::Impl::restart_at(uint64_t offset) {
    drop_read_ahead();
    decoded_in_raw.clear();
    chunk_ahead.clear();
    frames_verified.clear();
    chunk_loaded = false;
    raw_evicted = false;
    has_pending = false;
    ended = false;
    pos = offset;
    skipped_since_chunk = true;
    have_last_chunk = false;
    full_scan = false;
}

TraceError TraceReader::Impl::seek(uint64_t k) {
    seeked = true;
    if (index) {
        if (k >= index->submission_count()) {
            return error(TraceErrorCode::kInvalidArgument, 0,
                         "submission " + std::to_string(k) + " requested, the trace has " +
                             std::to_string(index->submission_count()));
        }
        const auto* chunks = index->chunks();
        const fbs::ChunkLocation* found = nullptr;
        for (const fbs::ChunkLocation* c : *chunks) {
            if (c->submission_count() > 0 && c->first_submission() <= k &&
                k - c->first_submission() < c->submission_count()) {
                found = c;
                break;
            }
        }
        if (!found || found->file_offset() < data_start || found->file_offset() >= size) {
            return error(TraceErrorCode::kBadIndex, index_offset,
                         "index lists no chunk holding submission " + std::to_string(k));
        }
        restart_at(found->file_offset());
    } else {
        restart_at(data_start);
    }
    RecordView v;
    while (next(&v)) {
        if (v.kind != fbs::RecordBody::QueueSubmit) continue;
        uint64_t at = v.record->body_as_QueueSubmit()->submission_index();
        if (at == k) {
            pending = v;
            has_pending = true;
            --stats.records;  // handed out again by next()
            return {};
        }
        if (at > k) break;
    }
    return error(TraceErrorCode::kInvalidArgument, 0,
                 "submission " + std::to_string(k) + " not found" +
                     (index ? "" : " (trace has no index)"));
}

}  // namespace clastrace::traces
