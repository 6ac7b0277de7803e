// SPDX-License-Identifier: Apache-2.0
// The trace reader's state, shared by the files that implement it: trace_reader.cpp (the public
// calls, the file header), trace_reader_chunks.cpp (chunks: payloads, checksums, decompression,
// the scan's order), trace_reader_records.cpp (records and their rules, next, seek),
// trace_reader_deltas.cpp (delta contents, read_contents), trace_reader_read_ahead.cpp (the
// task that reads the next chunk) and trace_reader_index.cpp (the index and what the scan checks
// against it).
#pragma once

#include <clastrace/traces/trace_reader.h>

#include <clastrace/common/hex.h>
#include <clastrace/traces/records.h>

#include "byte_source.h"
#include "chunk_bytes.h"
#include "delta_bases.h"
#include "file_format.h"
#include "read_ahead.h"
#include "read_ahead_thread.h"

#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <vector>

namespace clastrace::traces::reader {

constexpr size_t kMaxDamageKept = 1000;
constexpr uint32_t kReadAheadMinRawBytes = 256u << 10;
// Reading ahead a bigger chunk would hold two of them at once; the writer's chunks are 4 MiB.
constexpr uint32_t kReadAheadMaxRawBytes = 16u << 20;
// The writer never frames a record the verifier rejects, so a chunk whose frames break
// this often holds no records: one more message per frame would only cost time.
constexpr uint32_t kMaxBrokenFramesPerChunk = 4;
// ChunkLocation and ContentLocation sizes in the index, and the fixed part around them.
constexpr uint64_t kIndexBytesPerChunk = 32;
constexpr uint64_t kIndexBytesPerContent = 24;
constexpr uint64_t kIndexFixedBytes = 64u << 10;

// Checksums, magics and hashes read best at their full width.
inline std::string hex(uint64_t v) { return common::hex(v, 16); }

// Where the bytes of one content live: which chunk, and where its frame starts in it.
struct ContentPlace {
    uint64_t size;
    uint64_t chunk_offset;
    uint32_t raw_offset;
    bool seen_in_scan;  // defined by a record the scan already passed
    // The real bytes of the record here hash to its key (the scan or read_contents checked
    // them): the chunk checksums make every later reading of this place the same bytes.
    bool key_checked = false;
};

// The real bytes read_contents handed out recently, so that a content read again (replay lays
// each in at every snapshot naming it) costs a lookup and a copy instead of locating, verifying
// and hashing its record again, or decompressing a chunk the scan passed.
constexpr uint64_t kReadBackBudgetBytes = uint64_t{16} << 20;

enum class RecordStatus {
    kOk,
    kSkip,    // the record breaks a rule; the frames around it are fine
    kBroken,  // the frame itself is not a record (verifier, kind, body)
    kStopChunk,
};

bool known_byte_planes(uint8_t planes);
// Why a delta's `byte_planes` is refused.
std::string unknown_planes(uint8_t planes);

// out = `base` (the base's real bytes) XOR the delta `delta` laid out as `byte_planes` says.
// `out` may be `base`; it is `delta` only without planes.
void apply_delta(const uint8_t* delta, uint8_t byte_planes, const uint8_t* base, size_t n,
                 uint8_t* out);

// Where a record lies in file order: a delta's base must lie before it.
bool precedes(uint64_t chunk_a, uint32_t raw_a, uint64_t chunk_b, uint32_t raw_b);

}  // namespace clastrace::traces::reader

namespace clastrace::traces {

struct TraceReader::Impl {
    // The reader's own types (namespace reader), by their short names.
    using AheadContents = reader::AheadContents;
    using AheadDecoding = reader::AheadDecoding;
    using BytesPool = reader::BytesPool;
    using ChunkBytes = reader::ChunkBytes;
    using ChunkDecoder = reader::ChunkDecoder;
    using ChunkStatus = reader::ChunkStatus;
    using ContentPlace = reader::ContentPlace;
    using HeldChunk = reader::HeldChunk;
    using HeldChunks = reader::HeldChunks;
    using ReadAhead = reader::ReadAhead;
    using RealBytesCache = reader::RealBytesCache;
    using RecordStatus = reader::RecordStatus;
    using SharedBytes = reader::SharedBytes;
    using WholePlace = reader::WholePlace;

    std::string name;
    TraceReaderOptions options;
    std::unique_ptr<ByteSource> src;
    uint64_t size = 0;
    uint16_t version_major = 0;
    uint16_t version_minor = 0;
    std::vector<uint8_t> header_bytes;
    const fbs::TraceHeader* header = nullptr;
    unsigned hash_bits = 64;
    uint64_t data_start = format::kFileHeaderSize;

    // Index (when the file was finished).
    ChunkBytes index_raw;
    const fbs::TraceIndex* index = nullptr;
    uint64_t index_offset = 0;
    std::unordered_map<uint64_t, uint32_t>
        index_position;                  // chunk file offset -> place in index->chunks()
    std::vector<bool> index_chunk_read;  // by place: the scan read that records chunk

    // Decompression budget, shared with the read-ahead task.
    uint64_t raw_budget = 0;
    mutable std::atomic<uint64_t> raw_spent{0};
    bool budget_reported = false;
    bool budget_exhausted = false;

    // Streaming state.
    uint64_t pos = 0;
    bool ended = false;
    bool skipped_since_chunk = true;  // damage/seek since the last chunk: numbering may jump
    uint32_t expected_chunk_number = 0;
    ChunkDecoder decoder;
    ChunkBytes raw;
    // Read-ahead: a task decompressing the next chunk into ahead_raw with its own decoder.
    ChunkDecoder ahead_decoder;
    ChunkBytes ahead_raw;
    // The last two chunks loaded before `raw` where the task noted whole places (at
    // older_offset), kept for the task for kLoadsOlderKept loads after them (keep_loaded_as_older).
    std::array<ChunkBytes, reader::kOlderChunks> older_raw;
    std::array<uint64_t, reader::kOlderChunks> older_offset{UINT64_MAX, UINT64_MAX};
    uint32_t loads_past_older = 0;
    uint32_t loads_without_delta = 0;  // chunks loaded before the task saw a delta
    bool chunk_loaded = false;
    format::ChunkHeader chunk{};
    uint64_t chunk_offset = 0;
    size_t cursor = 0;
    uint32_t chunk_records_seen = 0;
    uint32_t chunk_submissions = 0;
    uint32_t chunk_broken_frames = 0;
    // Records chunks cut short after broken frames with no other frame read: holding nothing,
    // they are passed over undecompressed when read again (a seek: a zero bomb cost its whole
    // raw size each time), having said their damage the first time.
    std::unordered_set<uint64_t> chunks_of_broken_frames;
    bool chunk_cut_short = false;
    bool raw_evicted =
        false;  // the loaded chunk's bytes were freed for read_contents: decompress again
    uint64_t next_submission = 0;
    // The last records chunk handed out since the scan (re)started: a chunk numbered at or
    // below it, or starting before the submissions read, repeats records already handed out.
    bool have_last_chunk = false;
    uint32_t last_chunk_number = 0;
    // A scan from the first chunk, never repositioned: only it can tell which chunks the index lists in vain.
    bool full_scan = false;
    uint64_t scan_records_claimed = 0;
    bool seeked = false;
    bool has_pending = false;
    RecordView pending;

    std::unordered_map<uint64_t, ContentPlace> contents;
    ChunkBytes side_raw;
    uint64_t side_offset = UINT64_MAX;
    // Delta contents (MemoryContentsDelta, format 1.7): the raw offsets of the loaded chunk's
    // records decoded in place (rising: the scan decodes in order), and the real bytes of recent
    // contents, the bases of deltas to come, kept once the trace has shown one delta.
    std::vector<uint32_t> decoded_in_raw;
    std::shared_ptr<BytesPool> pool = std::make_shared<BytesPool>();
    RealBytesCache resolved;
    RealBytesCache read_back{reader::kReadBackBudgetBytes};
    ChunkBytes delta_copy;  // a delta's planes while it is decoded in place
    bool trace_has_deltas = false;
    // The read-ahead task decodes the deltas of the chunk it reads; the loaded chunk's results,
    // by raw offset, wait here for the checks of their records (decode_delta).
    AheadDecoding ahead_decoding;
    std::vector<AheadContents> chunk_ahead;
    // The loaded chunk's frames the task verified (ReadAhead::verified), and the first of them
    // parse_record has not passed yet.
    std::vector<uint32_t> frames_verified;
    size_t next_verified = 0;
    bool verified_ahead(uint32_t at) {
        while (next_verified < frames_verified.size() && frames_verified[next_verified] < at)
            ++next_verified;
        return next_verified < frames_verified.size() && frames_verified[next_verified] == at;
    }

    std::vector<TraceError> damage;
    uint64_t damage_total = 0;
    TraceReadStats stats;

    // The read-ahead thread. Last, so that it is destroyed first: its job touches the members
    // above (the decoder, buffers, bases and pool of the task, the source, the budget), which
    // must outlive it however the reader goes away.
    reader::ReadAheadThread<ReadAhead> ahead;

    ~Impl() { drop_read_ahead(); }

    // TraceReadStats::chunk_buffer_bytes; waits for the read-ahead task, whose buffers it counts.
    uint64_t chunk_buffer_bytes();

    TraceError error(TraceErrorCode code, uint64_t offset, const std::string& problem) const {
        return make_trace_error(code, name, offset, problem);
    }
    void report(TraceErrorCode code, uint64_t offset, const std::string& problem) {
        ++damage_total;
        if (damage.size() < reader::kMaxDamageKept) damage.push_back(error(code, offset, problem));
    }
    void report(TraceError e) {
        ++damage_total;
        if (damage.size() < reader::kMaxDamageKept) damage.push_back(std::move(e));
    }
    // For problems that can repeat per record: past the kept ones, counting costs no message.
    template <class MakeProblem>
    void report_with(TraceErrorCode code, uint64_t offset, MakeProblem&& problem) {
        ++damage_total;
        if (damage.size() < reader::kMaxDamageKept)
            damage.push_back(error(code, offset, problem()));
    }

    // Takes n bytes from the decompression budget; false (nothing taken) when they do not fit.
    bool take_from_budget(uint64_t n) const;

    // Reads, checks and decompresses the chunk whose header is at `offset`.
    ChunkStatus read_chunk(uint64_t offset, format::ChunkHeader* h, ChunkBytes* out,
                           TraceError* err);

    // decompress_payload on the reader's own thread and decoder, noting a spent budget.
    ChunkStatus decompress(uint64_t offset, const format::ChunkHeader& h, ChunkBytes* out,
                           TraceError* err);

    // Frees the bytes read_contents keeps of another chunk when they are big (one big buffer
    // at a time); the chunk is read again when asked for.
    void release_side_chunk_if_big();

    // Header and compressed payload of the chunk at `offset` into d.compressed, checksums
    // checked, nothing decompressed. This and decompress_payload are safe on the read-ahead
    // task: they touch only `d`, their outputs, the budget and the (thread-safe) source.
    ChunkStatus read_checked_payload(ChunkDecoder& d, uint64_t offset, format::ChunkHeader* h,
                                     TraceError* err) const;

    // Decompresses d.compressed (read by read_checked_payload for header h) into `out`.
    ChunkStatus decompress_payload(ChunkDecoder& d, uint64_t offset, const format::ChunkHeader& h,
                                   ChunkBytes* out, TraceError* err) const;

    // The largest index a file of this size can need: an entry per chunk (each at least a
    // header) and per content (each costs the file at least its 8-byte key twice, in its
    // record and in the index; counted at 8 for margin), within the format's limit.
    uint64_t plausible_index_raw_bytes() const;

    // Finds the next offset >= from holding a chunk header whose checksum holds.
    uint64_t find_next_chunk(uint64_t from);

    void resync(uint64_t from);

    // "chunk N record K (raw offset R)": where a record's problems are, at the chunk's offset.
    std::string record_place(uint32_t raw_offset) const;
    // A problem of the loaded chunk's record at raw offset `at`: record_place(at) followed by
    // what `problem` says (": ..." or " (kind): ...").
    template <class MakeProblem>
    void report_record(TraceErrorCode code, uint32_t at, MakeProblem&& problem) {
        report_with(code, chunk_offset, [&] { return record_place(at) + problem(); });
    }

    // Decodes the record at `cursor` of the loaded chunk.
    RecordStatus parse_record(RecordView* out);

    // Rules beyond the verifier: content keys, snapshot references, submission order.
    bool check_record(const fbs::Record& record, uint32_t at);

    // Turns the delta `c` (in the loaded chunk at raw offset `at`) into its real bytes, in
    // place, so that every consumer of the record sees them. False (reported) when its base is
    // unknown, later in the file, of another size or unreadable, or its layout is unknown.
    // When the read-ahead task decoded it against the same base bytes, its result is copied in
    // (*ahead_bytes: those bytes, to keep as a base).
    bool decode_delta(const ContentsRecord& c, uint32_t at, SharedBytes* ahead_bytes);

    // decode_delta on this thread: the base's real bytes are those the scan kept (usually), else
    // resolved through its chain; the planes are read from a copy, as each output byte gathers
    // from all four of them.
    TraceError decode_delta_here(const ContentsRecord& c, uint8_t* data);

    // What the read-ahead task made of the record at raw offset `at` of the loaded chunk.
    const AheadContents* ahead_contents_at(uint32_t at) const;

    // True when the task decoded delta `c` against the very bytes this thread would use: the
    // base bytes it keeps (the same buffer, not merely equal bytes), or, keeping none, those of
    // the whole record at the base's place (which resolve_contents would read and key-check).
    bool ahead_used_my_base(const AheadContents& a, const ContentsRecord& c,
                            const ContentPlace& base) const;

    // The task's copy of whole contents `c` (at raw offset `at` of the loaded chunk): the
    // same bytes, copied on the task.
    SharedBytes ahead_whole_copy(const ContentsRecord& c, uint32_t at) const;

    SharedBytes copy_of(const uint8_t* data, size_t n);

    // Keeps real bytes as a base for deltas to come: the task's copy when there is one.
    void keep_real_bytes(uint64_t hash, const uint8_t* data, size_t n, SharedBytes ahead);

    bool decoded_in_place(uint32_t raw_offset) const {
        return std::binary_search(decoded_in_raw.begin(), decoded_in_raw.end(), raw_offset);
    }

    void close_chunk();

    // A chunk is cut short after its first few broken frames: the rest of a chunk that
    // breaks like that (a hostile one: 256 MiB of zeros is 2^25 broken frames) holds nothing.
    void stop_chunk_after_broken_frames();

    // The chunk being read, again, after read_contents freed its bytes for another big chunk.
    bool reload_evicted_chunk();

    // Budget damage is said once; other errors each time.
    void report_budget_or(TraceError err);

    uint64_t ahead_started_at = UINT64_MAX;
    uint64_t ahead_offset() const { return ahead_started_at; }

    // Reads the chunk at `offset` on the task while the reader's thread reads `held.loaded`.
    void start_read_ahead(uint64_t offset, HeldChunks held);

    // Before the loaded chunk's buffer takes another chunk (no task runs): while the trace has
    // shown no delta, its bytes stay as the older chunk the task may read a range's first base
    // from (frames bigger than a chunk put it two chunks back), instead of decompressing it again.
    void keep_loaded_as_older();

    // The chunks the task may read besides its own (HeldChunk): `loaded` and the older ones.
    HeldChunks held_chunks(HeldChunk loaded) const;

    // The read-ahead task's result; nullopt when the task failed (it threw: out of memory) or
    // its read of the file did (a read error may be transient, unlike a verdict on bytes read),
    // and the chunk is then read again on this thread, whose errors carry the file and offset.
    std::optional<ReadAhead> take_read_ahead();

    // On the read-ahead task: the real bytes of the contents of chunk `r` (at `offset`) that it
    // can make (deltas whose base it holds, and once the trace has shown deltas, contents stored
    // whole), for the reader's thread to check and take. The records are checked again there,
    // with their damage reported; here a frame that breaks a rule is passed over. Touches only
    // ahead_decoding, ahead_decoder, the pool, the budget and the (thread-safe) source.
    std::vector<AheadContents> decode_ahead(uint64_t offset, const ChunkBytes& r, HeldChunks held);

    // On the task: delta `c` (at made->raw_offset of chunk `r`) XORed with the base the task
    // holds, or with the base's whole record read from where the task saw it.
    bool decode_delta_ahead(uint64_t offset, const ChunkBytes& r, HeldChunks held,
                            const ContentsRecord& c, AheadContents* made, bool* read_a_base);

    // On the task: whole contents `hash` at `place`, from chunk `r` (at `offset`), a chunk the
    // reader's thread holds, or else decompressed with the task's decoder (*decompressed set), its
    // key checked (as resolve_contents checks it); null when anything is off, which leaves the
    // delta to the reader's thread.
    SharedBytes read_whole_ahead(uint64_t offset, const ChunkBytes& r, HeldChunks held,
                                 uint64_t hash, WholePlace place, bool* decompressed);

    void drop_read_ahead();

    // The chunk at `pos`: from the read-ahead when it read this offset, else read here.
    // With *have_raw false and status ok only the checked compressed payload is in `decoder`.
    ChunkStatus take_chunk(format::ChunkHeader* h, TraceError* err, bool* have_raw);

    // Loads the next intact record chunk; false at the end of the records.
    bool advance_chunk();

    // The chunk the next one is checked against (its number, its first submission), and
    // against which a repeated or reordered one is told.
    void follow_chunk(const format::ChunkHeader& h);
    void skip_unknown_kind(uint64_t here, const format::ChunkHeader& h);
    void check_chunk_sequence(uint64_t here, const format::ChunkHeader& h);
    void enter_chunk(uint64_t here, const format::ChunkHeader& h);

    // False for a chunk that repeats or goes back (a duplicated or reordered chunk): its
    // records would hand out submissions already handed out, so they are skipped.
    bool in_order(uint64_t at, const format::ChunkHeader& h);

    // A records chunk's header against the index's entry for its offset.
    void check_chunk_against_index(uint64_t at, const format::ChunkHeader& h);

    // QueueSubmits of a fully read chunk against its index entry.
    void check_submissions_against_index();

    // At the end of a scan from the first chunk: chunks the index lists that were not read,
    // and, when nothing else was damaged, the index's totals against what was read.
    void finish_scan();

    // True when this index chunk ends the records: the one the trailer points at, or,
    // without a usable trailer at the end, one followed by a trailer. Any other index
    // chunk is damage, and the chunks after it are still read.
    bool reached_index_chunk(uint64_t at, uint64_t after);

    bool next(RecordView* out);

    void restart_at(uint64_t offset);

    TraceError seek(uint64_t k);

    // The record of contents `hash`, from the loaded chunk or the one read_contents keeps
    // (decompressed when needed), and whether it holds the real bytes (stored whole, or a delta
    // the scan decoded); valid until the next locate or chunk change. The chunk being
    // read gives a big buffer up for it only when `may_evict_raw` (not while a record of it is
    // being decoded).
    TraceError locate(uint64_t hash, bool may_evict_raw, ContentsRecord* found, ContentPlace* where,
                      bool* real);

    // The real bytes of contents `hash`: a delta's chain of bases is walked back to contents
    // held whole (stored whole, decoded by the scan, or kept in `resolved`), then XORed forward.
    // Each base must lie before its delta, so the walk ends, however the file was crafted.
    // The real bytes of every later reading go to `read_back` (unless `resolved` keeps them).
    TraceError resolve_contents(uint64_t hash, std::vector<uint8_t>* out, bool may_evict_raw);
    // resolve_contents' walk back through the chain of bases, its result kept nowhere.
    TraceError resolve_uncached(uint64_t hash, std::vector<uint8_t>* out, bool may_evict_raw);

    // The real bytes of contents `hash` that a cache keeps: the scan's bases or read_contents'.
    SharedBytes known_real_bytes(uint64_t hash) const;

    // True when the real bytes `data` of the record at `place` (contents `hash`, located
    // just now) hash to `hash`: hashed once per place, then trusted (ContentPlace::key_checked).
    bool key_holds(uint64_t hash, const ContentPlace& place, const uint8_t* data, size_t n,
                   uint64_t seed);

    TraceError read_contents(uint64_t hash, std::vector<uint8_t>* out) {
        return resolve_contents(hash, out, true);
    }

    // The bytes of the last read_contents_view: a cache's (shared, so eviction leaves them be),
    // or, for contents too big for the caches, view_scratch.
    SharedBytes viewed;
    std::vector<uint8_t> view_scratch;
    TraceError read_contents_view(uint64_t hash, std::span<const uint8_t>* out);

    // File header, trace header and (if intact) trailer + index. Fatal problems only
    // for what makes the file unreadable; the rest is damage.
    TraceError open();

    std::vector<uint8_t> read_small(uint64_t at, size_t n);

    void open_index();

    // The index's chunk list on its own: offsets rising inside the records, each chunk
    // starting where the submissions before it end, totals the sum of the entries. The
    // scan then compares each entry with the chunk at its offset.
    void check_index_entries();

    // True for an entry placing its chunk at an offset an earlier entry already placed one at:
    // index_position keeps the earlier, and check_index_entries names both.
    bool repeats_an_offset(uint32_t entry) const;

    // The reader's lookup of the index, whatever the file says: one read flag per entry, and
    // each offset leads to an entry placing a chunk at that offset (a hostile index listing
    // an offset twice keeps its first entry). Contents placed by the index lie in a listed chunk.
    bool chunk_index_holds() const;
};

}  // namespace clastrace::traces
