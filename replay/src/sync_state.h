// SPDX-License-Identifier: Apache-2.0
// The model's data layout: per-address access records, the per-queue barrier log, and the
// semaphore/event bookkeeping. Internal to the sync_*.cpp files (sync_model_internal.hpp).
#pragma once

#include <array>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <vector>

#include "clastrace/replay/hazard_report.h"
#include "clastrace/replay/sync_masks.h"
#include "clastrace/replay/sync_types.h"

namespace clastrace::replay::detail {

// Events are modelled as virtual pipeline stages: vkCmdSetEvent chains what is in its first
// scope into the event's stage bit, vkCmdWaitEvents chains that bit into its second scope.
// Nothing else names these bits, so later barriers can neither add nor remove them.
constexpr StageMask kEventStageBits = 0xFFFF000000000000ull;
constexpr int kFirstEventBit = 48;
constexpr int kEventSlots = 16;

inline StageMask source_scope_of(StageMask m) { return source_scope(m) & ~kEventStageBits; }
inline StageMask destination_scope_of(StageMask m) {
    return destination_scope(m) & ~kEventStageBits;
}

// A list that is empty in nearly every record (a write visible to more than two scopes, a
// record a narrow semaphore signal took in): one pointer until its first element, so the
// records holding it stay small and copying an empty one is a null test.
template <class T>
class RareList {
public:
    RareList() = default;
    RareList(const RareList& o) { *this = o; }
    RareList(RareList&&) = default;
    RareList& operator=(RareList&&) = default;
    RareList& operator=(const RareList& o) {
        if (o.empty())
            clear();
        else if (items_)
            *items_ = *o.items_;
        else
            items_ = std::make_unique<std::vector<T>>(*o.items_);
        return *this;
    }
    bool empty() const { return !items_ || items_->empty(); }
    std::size_t size() const { return items_ ? items_->size() : 0; }
    T& operator[](std::size_t i) { return (*items_)[i]; }
    const T& operator[](std::size_t i) const { return (*items_)[i]; }
    const T* begin() const { return items_ ? items_->data() : nullptr; }
    const T* end() const { return items_ ? items_->data() + items_->size() : nullptr; }
    void push_back(const T& t) {
        if (!items_) items_ = std::make_unique<std::vector<T>>();
        items_->push_back(t);
    }
    void clear() {
        if (items_) items_->clear();
    }

private:
    std::unique_ptr<std::vector<T>> items_;
};

// The (stage, access) pairs a write was made visible to, as a union of rectangles
// (destination stages x destination accesses of the barriers that made it visible). Almost
// always one or two; more spill to the heap rather than merge, which would hide hazards.
struct Visibility {
    struct Rect {
        StageMask stages;
        AccessMask accesses;
    };
    std::array<Rect, 2> inline_rects{};
    uint8_t inline_count = 0;
    RareList<Rect> more;

    void clear() {
        inline_count = 0;
        more.clear();
    }

    std::size_t size() const { return inline_count + more.size(); }
    const Rect& at(std::size_t i) const {
        return i < inline_count ? inline_rects[i] : more[i - inline_count];
    }
    Rect& at(std::size_t i) { return i < inline_count ? inline_rects[i] : more[i - inline_count]; }

    // Returns true when the rectangle went to the heap.
    bool add(StageMask stages, AccessMask accesses) {
        if (!stages || !accesses) return false;
        for (std::size_t i = 0; i < size(); ++i) {
            Rect& r = at(i);
            if ((r.stages & stages) == stages && (r.accesses & accesses) == accesses) return false;
            if (r.stages == stages) {
                r.accesses |= accesses;
                return false;
            }
            if (r.accesses == accesses) {
                r.stages |= stages;
                return false;
            }
        }
        if (inline_count < inline_rects.size()) {
            inline_rects[inline_count++] = {stages, accesses};
            return false;
        }
        more.push_back({stages, accesses});
        return true;
    }
    bool covers(StageMask stage, AccessMask accesses) const {
        for (AccessMask m = accesses; m; m &= m - 1) {
            const AccessMask bit = m & (~m + 1);
            bool found = false;
            for (std::size_t i = 0; i < size() && !found; ++i)
                found = (at(i).stages & stage) && (at(i).accesses & bit);
            if (!found) return false;
        }
        return true;
    }
};

// What the dependency chains after an access have reached so far.
// A semaphore signal whose stage mask leaves some device stages out of its first scope
// (vkQueueSubmit2 with a narrow VkSemaphoreSubmitInfo::stageMask). Signals whose scope is
// every stage need no bookkeeping: their clock alone says what they cover.
struct SignalMembership {
    uint32_t signal = 0;     // narrow signal id
    bool available = false;  // the write is in the signal's first access scope too
};

struct ChainState {
    StageMask chain = 0;  // stages whose later work is execution-ordered after the access
    StageMask avail = 0;  // same, for chains that began with an availability operation (writes)
    Visibility visible;   // (stage, access) pairs the write is visible to
    // Narrow signals whose first scope took the access in (see kSignal log entries).
    RareList<SignalMembership> signals;
};

struct Record {
    uint64_t tag = 0;       // unique per command; execution order on its queue
    AddressRange range;     // the whole access, for reports
    StageMask stage = 0;    // one atomic stage
    AccessMask access = 0;  // as given, for reports
    AccessMask atoms = 0;   // atomic accesses, for checks
    // Index into SyncModel::State::commands: the command's CommandRef is kept once there, not
    // in every segment the access covers (reports alone read it).
    uint32_t command = 0;
    uint32_t field = 0;  // an element run: the field's text before the index, e.g. "srcInfosArray["
    // An element run (SyncModel::record_accesses): element k is the byte range
    // [range.begin + k * element_bytes, +element_bytes), named field + (first_element + k) +
    // field_suffix. Hazards are decided per segment as for any record and named per element.
    uint32_t element_bytes = 0;  // 0: one access
    uint32_t first_element = 0;
    uint32_t field_suffix = 0;
    uint32_t log_pos = 0;  // absolute position in its queue's log applied up to
    uint16_t queue = 0;    // queue slot, or kHostSlot
    bool is_write = false;
    bool possible = false;   // Access::possible
    bool completed = false;  // retired by a host wait, kept only because the host cannot see it
    ChainState sync;
};

constexpr uint16_t kHostSlot = 0xFFFF;

// std::optional<Record>'s interface for a record kept on the heap: one pointer while empty.
// For Segment::possible_write, empty in all but cheap-mode dispatch traces, where an empty
// Record's bytes would sit in every segment.
class HeapRecord {
public:
    HeapRecord() = default;
    HeapRecord(const HeapRecord& o) : record_(o ? std::make_unique<Record>(*o) : nullptr) {}
    HeapRecord(HeapRecord&&) = default;
    HeapRecord& operator=(HeapRecord&&) = default;
    HeapRecord& operator=(const HeapRecord& o) {
        if (o)
            *this = *o;
        else
            reset();
        return *this;
    }
    HeapRecord& operator=(const Record& r) {
        if (record_)
            *record_ = r;
        else
            record_ = std::make_unique<Record>(r);
        return *this;
    }
    explicit operator bool() const { return record_ != nullptr; }
    Record& operator*() const { return *record_; }
    Record* operator->() const { return record_.get(); }
    void reset() { record_.reset(); }

private:
    std::unique_ptr<Record> record_;
};

// What the model knows about one address segment (its bounds live in the SegmentStore).
struct Segment {
    std::optional<Record> write;
    std::vector<Record> reads;  // the latest read per (queue, stage) since the write
    // Cheap mode's possible write of all device-address memory (a dispatch or draw whose shaders
    // may write through addresses), held beside the certain write so it never hides one from
    // later reads; only later reads are checked against it (docs/replay.md, "Possible hazards").
    HeapRecord possible_write;
    bool empty() const { return !write && !possible_write && reads.empty(); }
    void clear() {
        write.reset();
        possible_write.reset();
        reads.clear();
    }
};

// Barriers as stored in a queue's log, scopes already normalized.
struct LoggedBarrier {
    StageMask src_scope = 0;
    StageMask dst_scope = 0;
    AccessMask src_atoms = 0;
    AccessMask dst_atoms = 0;
    AddressRange range;
    bool global = true;
};

constexpr uint32_t kNoRun = 0xFFFFFFFFu;

// kSignal: a narrow semaphore signal at this point of the queue; catching a record up
// over it notes whether the signal's first scope took the record in.
enum class EntryKind : uint8_t { kBarrier, kImport, kEventSet, kEventWait, kSignal };

struct LogEntry {
    EntryKind kind = EntryKind::kBarrier;
    bool v1_event = false;  // event set without access masks (vkCmdSetEvent)
    uint32_t first = 0;     // absolute index into the queue's barrier pool
    uint32_t count = 0;
    uint32_t import_index = 0;  // absolute index into the queue's imports
    StageMask event_bits = 0;   // kSignal: the signal's first synchronization scope
    uint32_t signal = 0;        // kSignal: narrow signal id
    // Consecutive identical single-barrier entries form a run; applying one barrier twice
    // changes nothing, so catching up applies a run once. run_end is kept on the run's head.
    uint32_t run_start = kNoRun;
    uint32_t run_end = 0;
};

using Clock = std::vector<uint64_t>;  // per queue slot: accesses with a smaller tag are covered

struct Import {
    uint32_t log_pos = 0;
    Clock own;         // what this wait's signal covers
    Clock cumulative;  // what all waits up to this one cover (monotone: binary search)
    StageMask dst_scope = 0;
    uint32_t signal = 0;        // narrow signal id, 0 when the signal's scope is every stage
    uint16_t signal_queue = 0;  // queue slot that signaled (narrow signals only)
    // Only for the advice on a hazard this wait orders but whose stage it misses
    // (sync_wait_advice.cpp): the semaphore, the waiting submission, its stage mask as given.
    uint64_t semaphore = 0;
    uint32_t submission = 0;
    StageMask wait_stages = 0;
    StageMask signal_stages = 0;  // a narrow signal's stage mask as given, and its submission
    uint32_t signal_submission = 0;
};

struct Queue {
    QueueId id = 0;
    std::vector<LogEntry> log;
    uint32_t log_base = 0;
    std::vector<LoggedBarrier> pool;
    uint32_t pool_base = 0;
    std::vector<Import> imports;
    uint32_t imports_base = 0;
    Clock known;
    uint64_t complete = 0;  // accesses with a smaller tag finished and were waited for by the host
    // Absolute log positions, ascending. A "full" entry is a global barrier from every device
    // stage and write to every device stage and access: it subsumes everything before it.
    // A "special" entry can add what a full barrier does not (host visibility, event bits).
    std::vector<uint32_t> full_positions;
    std::vector<uint32_t> special_positions;
    std::size_t log_size_after_trim = 0;
    uint32_t log_end() const { return log_base + uint32_t(log.size()); }
};

struct NarrowSignal {
    uint32_t signal = 0;  // 0: the signal's scope is every stage
    uint16_t queue = 0;
    // Only for the advice (sync_wait_advice.cpp): the stage mask as given, the submission.
    StageMask stages = 0;
    uint32_t submission = 0;
};

struct SemaphoreState {
    std::optional<Clock> binary_signal;
    NarrowSignal binary_narrow;
    std::map<uint64_t, Clock> timeline;  // value -> what the signal covers
    std::map<uint64_t, NarrowSignal> timeline_narrow;
};

struct EventState {
    int slot = -1;
    bool v1 = false;
    uint64_t set_serial = 0;
};

struct HazardKey {
    uint64_t prior_tag, later_tag;
    uint32_t prior_field, later_field;
    HazardClass hazard;
    friend bool operator==(const HazardKey&, const HazardKey&) = default;
};
struct HazardKeyHash {
    std::size_t operator()(const HazardKey& k) const {
        uint64_t h = k.prior_tag * 0x9E3779B97F4A7C15ull ^ (k.later_tag + 0x632BE59BD9B4E019ull);
        h ^= (uint64_t(k.prior_field) << 32 | k.later_field) * 0xC2B2AE3D27D4EB4Full;
        h ^= uint64_t(k.hazard) << 7;
        return std::size_t(h ^ (h >> 29));
    }
};

inline bool contains(const AddressRange& outer, uint64_t begin, uint64_t end) {
    return outer.begin <= begin && end <= outer.end;
}

inline bool same_barrier(const LoggedBarrier& a, const LoggedBarrier& b) {
    return a.src_scope == b.src_scope && a.dst_scope == b.dst_scope && a.src_atoms == b.src_atoms &&
           a.dst_atoms == b.dst_atoms && a.global == b.global && (a.global || a.range == b.range);
}

inline const StageMask kDeviceStages = all_device_stages();
inline const AccessMask kWriteAtoms = all_write_accesses();
inline const AccessMask kAllAtoms = all_read_accesses() | all_write_accesses();

}  // namespace clastrace::replay::detail
