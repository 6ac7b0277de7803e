// SPDX-License-Identifier: Apache-2.0
// SyncModel's state, shared by the files that implement it, one concern each:
//   sync_bookkeeping.cpp       queue slots, interned field names
//   sync_barrier_log.cpp       the lazy per-queue barrier log records catch up over
//   sync_hazard_detection.cpp  is an earlier access ordered and visible; findings and reports
//   sync_address_map.cpp       the segments accesses are recorded into
//   sync_element_runs.cpp      record_accesses' batching into element runs
//   sync_barriers.cpp          barriers and events into the log
//   sync_host_waits.cpp        host waits: retiring completed work, trimming the logs
//   sync_model.cpp             the public API (SyncModel's members)
// The data layout itself is in sync_state.h.
#pragma once

#include "clastrace/replay/sync_model.h"

#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "segment_store.h"
#include "sync_state.h"

namespace clastrace::replay {

using namespace detail;

struct SyncModel::State {
    SyncOptions options;
    SyncStats stats;
    std::vector<HazardReport> reports;
    std::unordered_set<HazardKey, HazardKeyHash> seen;

    SegmentStore<Segment> segments;
    // The commands of the accesses recorded, named by index from each Record (Record::command);
    // collect_commands drops those no segment names any more.
    std::vector<CommandRef> commands;
    uint32_t current_command = 0;  // the index of the command command_tag last saw
    std::vector<Queue> queues;
    std::unordered_map<uint64_t, SemaphoreState> semaphores;
    struct FenceSignal {
        Clock clock;
        // The submission it signals after, for the advice on host-write races
        // (sync_wait_advice.cpp); none for an image acquire's fence.
        std::optional<uint32_t> submission;
    };
    std::unordered_map<uint64_t, FenceSignal> fences;
    // The last fence of a submission the host waited on, with that submission.
    std::optional<std::pair<uint64_t, uint32_t>> last_fence_wait;
    uint32_t current_submission = 0;
    std::unordered_map<uint64_t, EventState> events;
    std::array<uint64_t, kEventSlots> slot_owner{};  // event handle holding each slot (0 = free)
    std::array<bool, kEventSlots> slot_used{};
    int next_slot = 0;
    uint64_t set_serial = 0;

    std::vector<std::string> field_names;  // interned: id -> text ("" is id 0)
    struct FieldText {
        std::size_t offset = 0;  // into field_arena
        std::size_t length = 0;
    };
    std::vector<FieldText> field_texts;  // id -> its text in field_arena
    // Each interned name split once around its first index ("srcInfosArray[" 12
    // "].vertexBuffer", both parts interned too), so record_accesses forms its element runs
    // by comparing ids instead of parsing and comparing every access's text.
    struct FieldShape {
        bool indexed = false;
        uint32_t prefix = 0, suffix = 0;
        uint64_t index = 0;
    };
    std::vector<FieldShape> field_shapes;

    // record_accesses' working lists, kept to spare the allocations per command.
    struct Run {  // an element run being formed: consecutive "x[i]" accesses
        uint32_t prefix = 0, suffix = 0;  // interned texts around the index
        uint64_t first = 0, next = 0, bytes = 0;
        AddressRange range;
        uint32_t head = 0, last = 0, count = 1, members_at = 0;
    };
    struct BatchScratch {
        std::vector<std::pair<uint64_t, uint32_t>> by_begin, sort_scratch;
        std::vector<uint8_t> pinned;
        std::vector<int32_t> run_of, next_member;
        std::vector<uint32_t> members;
        std::vector<Run> runs;
        std::vector<uint32_t> field_of;
        // intern_fields' guesses: the field that followed each field in the last command
        // that had it (by id; UINT32_MAX: none yet), and the field a command began with.
        std::vector<uint32_t> next_field;
        uint32_t first_field = UINT32_MAX;
        Record record;
    } batch;
    // batch.field_of: each access's interned field.
    void intern_fields(std::span<const Access> accesses);
    // record_accesses' batching (sync_element_runs.cpp).
    void pin_overlapping(std::span<const Access> accesses);
    void form_element_runs(std::span<const Access> accesses);

    uint64_t tag = 1;
    CommandRef last_command;
    uint16_t last_queue = 0;
    bool last_was_access = false;
    uint16_t current_queue = 0;
    bool in_submission = false;
    uint32_t next_signal = 0;  // narrow semaphore signal ids
    bool any_narrow =
        false;              // a narrow signal was seen: records are caught up before foreign views
    int foreign_depth = 0;  // nesting of foreign views through chains of narrow signals

    // ------------------------------------------------------------------ bookkeeping (sync_bookkeeping.cpp)
    uint16_t queue_slot(QueueId id);
    // queue_slot()'s inverse: the queue of a record's slot (kHostQueue for kHostSlot).
    QueueId queue_of_slot(uint16_t slot) const {
        return slot == kHostSlot ? kHostQueue : queues[slot].id;
    }
    uint64_t covered(const Clock& c, uint16_t slot) const { return slot < c.size() ? c[slot] : 0; }

    // Every access names its field ("srcInfosArray[7].vertexBuffer": a few names per op
    // index), so interning runs once per access: an open-addressing table of (hash, id) over
    // field_names, with a word-at-a-time hash, instead of a node-based map hashing bytewise.
    // The texts are compared in one arena: names longer than the small-string buffer would
    // each sit in their own heap block, a cache miss per lookup.
    struct FieldSlot {
        uint64_t hash = 0;
        uint32_t id = UINT32_MAX;  // UINT32_MAX: empty
        uint32_t length = 0;
        std::size_t offset = 0;  // into field_arena
    };
    std::string field_arena;
    std::vector<FieldSlot> field_table = std::vector<FieldSlot>(64);

    static uint64_t field_hash(std::string_view v);

    uint32_t intern(std::string_view field);
    void place_field(FieldSlot slot);

    // Accesses of one command share a tag; a command is known by its reference and queue.
    // A new command's reference goes to `commands` (current_command).
    uint64_t command_tag(const CommandRef& command, uint16_t queue) {
        if (!(last_was_access && command == last_command && queue == last_queue)) {
            ++tag;
            current_command = uint32_t(commands.size());
            commands.push_back(command);
        }
        last_command = command;
        last_queue = queue;
        last_was_access = true;
        return tag;
    }
    uint64_t sync_tag() {
        last_was_access = false;
        return ++tag;
    }

    // ------------------------------------------------------------------ lazy barrier log (sync_barrier_log.cpp)
    void apply_barriers(const Queue& q, const LogEntry& e, ChainState& s, const Record& r,
                        bool home, uint64_t seg_begin, uint64_t seg_end);

    void apply_event_set(const Queue& q, const LogEntry& e, ChainState& s, const Record& r,
                         bool home, uint64_t seg_begin, uint64_t seg_end);

    void apply_event_wait(const Queue& q, const LogEntry& e, ChainState& s, const Record& r,
                          uint64_t seg_begin, uint64_t seg_end);

    void apply_entry(const Queue& q, uint32_t pos, ChainState& s, const Record& r, bool home,
                     uint64_t seg_begin, uint64_t seg_end);

    static bool settled(const Record& r);
    static void apply_full(Record& r);

    // Brings a record's chain state up to the end of its queue's log. Runs of ordinary
    // entries are skipped once the record is settled, or jumped over to the last full
    // barrier among them; only special entries are always applied.
    void catch_up(Record& r, uint64_t seg_begin, uint64_t seg_end);

    // The chain state of a record from another queue as seen from `w`: nothing until a
    // semaphore wait on `w` covers it, then that wait's stages and whatever follows on `w`.
    std::optional<ChainState> foreign_view(const Record& r, const Queue& w, uint64_t seg_begin,
                                           uint64_t seg_end);

    // Did the narrow signal `im` waited on take `r` into its first scope (and, for a write,
    // its access scope: *available)? The signal's clock covers r; its stage mask decides.
    bool in_signal(const Import& im, const Record& r, uint64_t seg_begin, uint64_t seg_end,
                   bool* available);

    // ------------------------------------------------------------------ hazard decisions (sync_hazard_detection.cpp)
    struct Later {
        const Record* record;
        uint16_t queue;
        bool deserialize;
    };

    // Is `prior` execution-ordered before `later`, and (when `need_visible`) is it visible?
    // Returns the fix to suggest when it is not; nullopt when ordered.
    std::optional<FixKind> unordered(Record& prior, const Later& later, bool need_visible,
                                     uint64_t seg_begin, uint64_t seg_end);

    struct Finding {
        HazardKey key;
        Record prior;  // a copy: the segment's record is replaced right after the check
        FixKind fix;
        AddressRange overlap;
        // The later access is one element of an element run: the element's field and bytes.
        bool later_element = false;
        uint32_t later_field = 0;
        AddressRange later_range;
        uint32_t order = 0;  // record_accesses: index of the later access in the command's list
        uint32_t later_record = 0;  // record_accesses: which of its records was the later access
    };

    // The element of an element run holding byte `at`: its field and bytes (a plain record:
    // its own). Interning here runs only on the hazard path.
    void element_of(const Record& r, uint64_t at, uint32_t* field, AddressRange* range);

    // Findings of one access are few, except when an element run meets another: then the
    // pairs of elements are many, and a linear search for the key would be quadratic.
    std::unordered_map<HazardKey, std::size_t, HazardKeyHash> found_index;

    void note_one(std::vector<Finding>& found, HazardKey key, const Record& prior,
                  const AddressRange& prior_range, const Record& later,
                  const AddressRange& later_range, FixKind fix, uint64_t begin, uint64_t end);

    void note(std::vector<Finding>& found, HazardClass hazard, const Record& prior,
              const Record& later, FixKind fix, uint64_t seg_begin, uint64_t seg_end);

    HazardAccess describe(const Record& r) const;

    void emit(const Finding& f, const Record& later);

    // ------------------------------------------------------------------ advice (sync_wait_advice.cpp)
    // What the application's own wait missed, when it had one: a semaphore wait that orders
    // the prior access but not the later access's stage, or a host wait on another
    // submission's fence. Empty when there was no such wait.
    std::string wait_advice(const Record& prior, const Record& later,
                            const HazardReport& report) const;
    // The same for a pipeline barrier or event set recorded between two accesses of one queue
    // that misses the hazard (stages, access masks or buffer range): names it and what it
    // leaves out.
    std::string barrier_advice(const Record& prior, const Record& later,
                               const HazardReport& report) const;
    // The last pipeline barriers' and event sets' commands (a ring), for barrier_advice: only
    // hazards read it, and a barrier that missed is nearly always one of the last few before
    // the later access.
    struct BarrierCommand {
        uint64_t tag = 0;
        uint16_t queue = 0;
        uint32_t log_pos = 0;  // its entry in the queue's log (gone once trimmed)
        CommandRef command;
    };
    static constexpr std::size_t kRecentBarriers = 64;
    std::vector<BarrierCommand> recent_barriers;
    std::size_t next_recent_barrier = 0;
    void remember_barrier(const CommandRef& command, uint64_t barrier_tag);

    // ------------------------------------------------------------------ the address map (sync_address_map.cpp)
    // Makes `at` a segment boundary if a segment straddles it.
    void split_at(uint64_t at) { segments.split_at(at); }

    // One pass over the segments [begin, end) touches: splits at the two ends, fills gaps
    // with fresh segments, and (a write) leaves one segment behind, so that overlapping
    // writes do not fragment memory byte by byte.
    // `collect`: findings go there instead of being reported (record_accesses orders them).
    void record(const Record& b, bool deserialize, std::vector<Finding>* collect = nullptr);

    void check_and_update(Segment& seg, uint64_t seg_begin, uint64_t seg_end, const Later& later,
                          std::vector<Finding>& found);

    // Memory the addresses resolve to (SyncModel::set_address_resolver); null: none.
    AddressResolver* resolver = nullptr;
    UnboundHandler on_unbound;
    std::vector<ResolvedRange> resolved;  // resolve()'s working list
    // Whether `range` reaches memory somewhere other than at its own addresses.
    bool resolves_elsewhere(AddressRange range);
    // record() at each bound part of the memory `b`'s range resolves to (the same command and
    // tag); unbound parts go to on_unbound with `access`.
    void record_resolved(const Record& b, const Access& access, bool deserialize);
    // `dependency` with its buffer barriers over the memory their ranges resolve to, kept in
    // `storage`.
    DependencyInfo resolve_barriers(const DependencyInfo& dependency,
                                    std::vector<BufferBarrier>& storage);

    // fill_record's last masks and their atoms: a command's accesses mostly share their stage
    // and access, so the expansion runs once per change, not per access.
    struct AtomicMasks {
        StageMask stage = 0;
        AccessMask access = 0;
        StageMask stage_atoms = 0;  // no stage and no access expand to nothing
        AccessMask access_atoms = 0;
    } last_masks;
    // A record of `a` by the command command_tag last saw (tag t).
    Record make_record(const Access& a, uint16_t queue, uint64_t t);
    // make_record into an existing record (record_accesses reuses one, sparing its vectors).
    void fill_record(Record& r, const Access& a, uint16_t queue, uint64_t t);
    void fill_record(Record& r, const Access& a, uint16_t queue, uint64_t t, uint32_t field);

    // Commands are appended per command and dropped here once no segment names them (every
    // Record's index moves to the kept list). Only between calls that record accesses, when
    // nothing else holds an index but current_command, and only once as many commands were
    // appended as a pass over the segments costs, so the pass stays a constant share of the
    // recording and the list within twice what segments name plus that.
    static constexpr std::size_t kCollectFloor = 64;
    std::size_t collect_at = kCollectFloor;
    std::vector<CommandRef> kept_commands;  // collect_commands' working lists
    std::vector<uint32_t> moved_to;
    void maybe_collect_commands() {
        if (commands.size() >= collect_at) collect_commands();
    }
    void collect_commands();

    // ------------------------------------------------------------------ barriers (sync_barriers.cpp)
    uint32_t pool_barriers(Queue& q, const DependencyInfo& dep);

    void log_barrier_entry(EntryKind kind, const DependencyInfo& dep, StageMask event_bits,
                           bool v1);

    // ------------------------------------------------------------------ host waits (sync_host_waits.cpp)
    // Accesses older than a queue's `complete` count as finished wherever they are met, so
    // dropping them (retire) only saves memory. A sweep costs a pass over every segment, so
    // fence and semaphore waits sweep only once the segments have doubled since the last
    // sweep (memory stays within twice what is live, plus kSweepFloor); idle waits always do.
    static constexpr std::size_t kSweepFloor = 1024;
    std::size_t sweep_at = kSweepFloor;

    void complete_through(const Clock& clock, bool always_sweep);

    bool all_complete(const Clock& c) const;

    // A timeline semaphore keeps one clock per value signalled, so an app counting frames
    // on it would grow the map with the trace. A value whose signal and next value's signal
    // are both complete can go: a wait on it finds that next value, whose extra coverage is
    // completed work, which orders nothing any more.
    void prune_timelines();

    // Drops what host waits proved finished; keeps completed writes the host cannot see yet.
    void retire();

    // Forgets log entries no live record can still need.
    void trim_logs();

    // Without host waits the log would grow with the trace: now and then bring every record
    // up to date and drop what none needs. Doubling keeps the cost amortized.
    void maybe_compact(const Queue& q);

    void compact();

    Clock snapshot_now(uint16_t slot);
};

}  // namespace clastrace::replay
