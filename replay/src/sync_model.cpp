#include "clastrace/replay/sync_model.hpp"

#include <algorithm>
#include <cstring>
#include <string>
#include <unordered_map>
#include <unordered_set>

#include "segment_store.hpp"
#include "sync_state.hpp"

namespace clastrace::replay {

using namespace detail;

namespace {

// "srcInfosArray[12].vertexBuffer" -> "srcInfosArray[", 12, "].vertexBuffer". Only the
// canonical spelling of the index (no leading zeros) counts, so the text rebuilt from the
// parts is the field itself.
bool split_indexed_field(std::string_view field, std::string_view* prefix, uint64_t* index, std::string_view* suffix) {
    const std::size_t open = field.find('[');
    if (open == std::string_view::npos) return false;
    std::size_t i = open + 1;
    uint64_t value = 0;
    while (i < field.size() && field[i] >= '0' && field[i] <= '9' && i - open <= 9) value = value * 10 + uint64_t(field[i++] - '0');
    const std::size_t digits = i - open - 1;
    if (digits == 0 || i >= field.size() || field[i] != ']' || (digits > 1 && field[open + 1] == '0')) return false;
    *prefix = field.substr(0, open + 1);
    *index = value;
    *suffix = field.substr(i);
    return true;
}

}  // namespace

struct SyncModel::State {
    SyncOptions options;
    SyncStats stats;
    std::vector<HazardReport> reports;
    std::unordered_set<HazardKey, HazardKeyHash> seen;

    SegmentStore<Segment> segments;
    std::vector<Queue> queues;
    std::unordered_map<uint64_t, SemaphoreState> semaphores;
    std::unordered_map<uint64_t, Clock> fences;
    std::unordered_map<uint64_t, EventState> events;
    std::array<uint64_t, kEventSlots> slot_owner{};  // event handle holding each slot (0 = free)
    std::array<bool, kEventSlots> slot_used{};
    int next_slot = 0;
    uint64_t set_serial = 0;

    std::vector<std::string> field_names;  // interned: id -> text ("" is id 0)
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
        std::vector<std::pair<uint64_t, uint32_t>> by_begin;
        std::vector<uint64_t> packed;
        std::vector<uint8_t> pinned;
        std::vector<int32_t> run_of, next_member;
        std::vector<uint32_t> members;
        std::vector<Run> runs;
        std::vector<uint32_t> field_of;
        Record record;
    } batch;

    uint64_t tag = 1;
    CommandRef last_command;
    uint16_t last_queue = 0;
    bool last_was_access = false;
    uint16_t current_queue = 0;
    bool in_submission = false;
    uint32_t next_signal = 0;   // narrow semaphore signal ids
    bool any_narrow = false;    // a narrow signal was seen: records are caught up before foreign views
    int foreign_depth = 0;      // nesting of foreign views through chains of narrow signals

    // ------------------------------------------------------------------ bookkeeping
    uint16_t queue_slot(QueueId id) {
        for (std::size_t i = 0; i < queues.size(); ++i)
            if (queues[i].id == id) return uint16_t(i);
        Queue q;
        q.id = id;
        queues.push_back(std::move(q));
        for (Queue& each : queues) each.known.resize(queues.size(), 0);
        for (auto& [handle, clock] : fences) clock.resize(queues.size(), 0);
        for (auto& [handle, sem] : semaphores) {
            if (sem.binary_signal) sem.binary_signal->resize(queues.size(), 0);
            for (auto& [value, clock] : sem.timeline) clock.resize(queues.size(), 0);
        }
        return uint16_t(queues.size() - 1);
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
        std::size_t offset = 0;    // into field_arena
    };
    std::string field_arena;
    std::vector<FieldSlot> field_table = std::vector<FieldSlot>(64);

    static uint64_t field_hash(std::string_view v) {
        uint64_t h = 0x9E3779B97F4A7C15ull ^ v.size();
        std::size_t i = 0;
        for (; i + 8 <= v.size(); i += 8) {
            uint64_t w;
            std::memcpy(&w, v.data() + i, 8);
            h = (h ^ w) * 0xFF51AFD7ED558CCDull;
            h ^= h >> 32;
        }
        uint64_t w = 0;
        if (i < v.size()) std::memcpy(&w, v.data() + i, v.size() - i);
        h = (h ^ w) * 0xC4CEB9FE1A85EC53ull;
        return h ^ (h >> 29);
    }

    uint32_t intern(std::string_view field) {
        const uint64_t h = field_hash(field);
        const std::size_t mask = field_table.size() - 1;
        for (std::size_t i = h & mask;; i = (i + 1) & mask) {
            const FieldSlot& slot = field_table[i];
            if (slot.id == UINT32_MAX) break;
            if (slot.hash == h && slot.length == field.size() &&
                (field.empty() || std::memcmp(field_arena.data() + slot.offset, field.data(), field.size()) == 0))
                return slot.id;
        }
        const uint32_t id = uint32_t(field_names.size());
        field_names.emplace_back(field);
        field_shapes.emplace_back();
        const std::size_t offset = field_arena.size();
        field_arena.append(field);
        if (2 * field_names.size() > field_table.size()) {
            std::vector<FieldSlot> old(2 * field_table.size());
            old.swap(field_table);
            for (const FieldSlot& slot : old)
                if (slot.id != UINT32_MAX) place_field(slot);
        }
        place_field({h, id, uint32_t(field.size()), offset});
        std::string_view prefix, suffix;
        uint64_t index = 0;
        const std::string name = field_names[id];  // the parts' interning may move field_names
        if (split_indexed_field(name, &prefix, &index, &suffix)) {
            const uint32_t prefix_id = intern(prefix), suffix_id = intern(suffix);  // shorter: ends
            field_shapes[id] = {true, prefix_id, suffix_id, index};
        }
        return id;
    }
    void place_field(FieldSlot slot) {
        const std::size_t mask = field_table.size() - 1;
        std::size_t i = slot.hash & mask;
        while (field_table[i].id != UINT32_MAX) i = (i + 1) & mask;
        field_table[i] = slot;
    }

    // Accesses of one command share a tag; a command is known by its reference and queue.
    uint64_t command_tag(const CommandRef& command, uint16_t queue) {
        if (!(last_was_access && command == last_command && queue == last_queue)) ++tag;
        last_command = command;
        last_queue = queue;
        last_was_access = true;
        return tag;
    }
    uint64_t sync_tag() {
        last_was_access = false;
        return ++tag;
    }

    // ------------------------------------------------------------------ lazy barrier log
    void apply_barriers(const Queue& q, const LogEntry& e, ChainState& s, const Record& r, bool home,
                        uint64_t seg_begin, uint64_t seg_end) {
        // All barriers of one command act at once: decide each against the state before any.
        StageMask add_chain = 0, add_avail = 0;
        uint64_t makes_visible = 0;  // bit i: barrier i makes the write visible
        const AccessMask write_atoms = r.atoms & kWriteAtoms;
        const uint32_t count = std::min<uint32_t>(e.count, 64);
        for (uint32_t i = 0; i < count; ++i) {
            const LoggedBarrier& b = q.pool[e.first + i - q.pool_base];
            if (!b.global && !contains(b.range, seg_begin, seg_end)) continue;
            const bool direct = home && (b.src_scope & r.stage);
            if (!direct && !(s.chain & b.src_scope)) continue;
            add_chain |= b.dst_scope;
            if (!r.is_write) continue;
            const bool in_access_scope = direct && (write_atoms & b.src_atoms) == write_atoms;
            if (in_access_scope || (s.avail & b.src_scope)) {
                add_avail |= b.dst_scope;
                makes_visible |= uint64_t(1) << i;
            }
        }
        s.chain |= add_chain;
        s.avail |= add_avail;
        for (uint64_t m = makes_visible; m; m &= m - 1) {
            const LoggedBarrier& b = q.pool[e.first + uint32_t(__builtin_ctzll(m)) - q.pool_base];
            stats.visibility_spills += s.visible.add(b.dst_scope, b.dst_atoms);
        }
    }

    void apply_event_set(const Queue& q, const LogEntry& e, ChainState& s, const Record& r, bool home,
                         uint64_t seg_begin, uint64_t seg_end) {
        // The slot may carry an older set of a reused event: this set starts it afresh.
        s.chain &= ~e.event_bits;
        s.avail &= ~e.event_bits;
        const AccessMask write_atoms = r.atoms & all_write_accesses();
        for (uint32_t i = 0; i < e.count; ++i) {
            const LoggedBarrier& b = q.pool[e.first + i - q.pool_base];
            if (!b.global && !contains(b.range, seg_begin, seg_end)) continue;
            const bool direct = home && (b.src_scope & r.stage);
            if (!direct && !(s.chain & b.src_scope & ~kEventStageBits)) continue;
            s.chain |= e.event_bits;
            if (!r.is_write) continue;
            const bool in_access_scope = direct && (e.v1_event || (write_atoms & b.src_atoms) == write_atoms);
            if (in_access_scope || (s.avail & b.src_scope & ~kEventStageBits)) s.avail |= e.event_bits;
        }
    }

    void apply_event_wait(const Queue& q, const LogEntry& e, ChainState& s, const Record& r, uint64_t seg_begin,
                          uint64_t seg_end) {
        if (!(s.chain & e.event_bits)) return;
        StageMask add_chain = 0, add_avail = 0;
        Visibility add_visible;
        const AccessMask write_atoms = r.atoms & all_write_accesses();
        for (uint32_t i = 0; i < e.count; ++i) {
            const LoggedBarrier& b = q.pool[e.first + i - q.pool_base];
            if (!b.global && !contains(b.range, seg_begin, seg_end)) continue;
            add_chain |= b.dst_scope;
            if (!r.is_write || !(s.avail & e.event_bits)) continue;
            // A v1 set names no accesses; the wait's source access mask stands in for it.
            if (e.v1_event && (write_atoms & b.src_atoms) != write_atoms) continue;
            add_avail |= b.dst_scope;
            add_visible.add(b.dst_scope, b.dst_atoms);
        }
        s.chain |= add_chain;
        s.avail |= add_avail;
        for (std::size_t i = 0; i < add_visible.size(); ++i)
            stats.visibility_spills += s.visible.add(add_visible.at(i).stages, add_visible.at(i).accesses);
    }

    void apply_entry(const Queue& q, uint32_t pos, ChainState& s, const Record& r, bool home, uint64_t seg_begin,
                     uint64_t seg_end) {
        const LogEntry& e = q.log[pos - q.log_base];
        ++stats.log_entries_applied;
        switch (e.kind) {
        case EntryKind::kBarrier: apply_barriers(q, e, s, r, home, seg_begin, seg_end); break;
        case EntryKind::kEventSet: apply_event_set(q, e, s, r, home, seg_begin, seg_end); break;
        case EntryKind::kEventWait: apply_event_wait(q, e, s, r, seg_begin, seg_end); break;
        case EntryKind::kSignal: {
            const bool direct = home && (r.stage & e.event_bits);
            if (direct || (s.chain & e.event_bits))
                s.signals.push_back({e.signal, !r.is_write || direct || (s.avail & e.event_bits) != 0});
            break;
        }
        case EntryKind::kImport: {
            const Import& im = q.imports[e.import_index - q.imports_base];
            bool available = true;
            if (covered(im.own, r.queue) > r.tag && (!im.signal || in_signal(im, r, seg_begin, seg_end, &available))) {
                s.chain |= im.dst_scope;
                if (r.is_write && available) {
                    s.avail |= im.dst_scope;
                    s.visible.add(im.dst_scope, all_read_accesses() | all_write_accesses());
                }
            }
            break;
        }
        }
    }

    static bool settled(const Record& r) {
        const StageMask device = all_device_stages();
        if ((r.sync.chain & device) != device) return false;
        if (!r.is_write) return true;
        if ((r.sync.avail & device) != device) return false;
        const AccessMask all = all_read_accesses() | all_write_accesses();
        for (std::size_t i = 0; i < r.sync.visible.size(); ++i) {
            const Visibility::Rect& rect = r.sync.visible.at(i);
            if ((rect.stages & device) == device && (rect.accesses & all) == all) return true;
        }
        return false;
    }
    static void apply_full(Record& r) {
        const StageMask device = all_device_stages();
        r.sync.chain |= device;
        if (!r.is_write) return;
        r.sync.avail |= device;
        r.sync.visible.add(device, all_read_accesses() | all_write_accesses());
    }

    // Brings a record's chain state up to the end of its queue's log. Runs of ordinary
    // entries are skipped once the record is settled, or jumped over to the last full
    // barrier among them; only special entries are always applied.
    void catch_up(Record& r, uint64_t seg_begin, uint64_t seg_end) {
        if (r.queue == kHostSlot || r.completed) return;
        const Queue& q = queues[r.queue];
        const uint32_t end = q.log_end();
        uint32_t pos = r.log_pos;
        while (pos < end) {
            auto sp = std::lower_bound(q.special_positions.begin(), q.special_positions.end(), pos);
            const uint32_t next_special = sp == q.special_positions.end() ? end : *sp;
            if (!settled(r)) {
                auto f = std::lower_bound(q.full_positions.begin(), q.full_positions.end(), next_special);
                if (f != q.full_positions.begin() && *(f - 1) >= pos) {
                    apply_full(r);
                    ++stats.log_entries_applied;
                    pos = *(f - 1) + 1;
                }
                while (pos < next_special && !settled(r)) {
                    const LogEntry& e = q.log[pos - q.log_base];
                    apply_entry(q, pos, r.sync, r, true, seg_begin, seg_end);
                    uint32_t next = pos + 1;
                    if (e.run_start != kNoRun && e.run_start >= q.log_base)
                        next = std::max(next, std::min(q.log[e.run_start - q.log_base].run_end, next_special));
                    pos = next;
                }
            }
            pos = next_special;
            if (pos < end) apply_entry(q, pos++, r.sync, r, true, seg_begin, seg_end);
        }
        r.log_pos = end;
    }

    // The chain state of a record from another queue as seen from `w`: nothing until a
    // semaphore wait on `w` covers it, then that wait's stages and whatever follows on `w`.
    std::optional<ChainState> foreign_view(const Record& r, const Queue& w, uint64_t seg_begin, uint64_t seg_end) {
        auto it = std::partition_point(w.imports.begin(), w.imports.end(),
                                       [&](const Import& im) { return covered(im.cumulative, r.queue) <= r.tag; });
        if (it == w.imports.end()) return std::nullopt;
        ChainState s;
        for (uint32_t pos = it->log_pos; pos < w.log_end(); ++pos) apply_entry(w, pos, s, r, false, seg_begin, seg_end);
        return s;
    }

    // Did the narrow signal `im` waited on take `r` into its first scope (and, for a write,
    // its access scope: *available)? The signal's clock covers r; its stage mask decides.
    bool in_signal(const Import& im, const Record& r, uint64_t seg_begin, uint64_t seg_end, bool* available) {
        const std::vector<SignalMembership>* list = &r.sync.signals;  // r's own queue signaled: caught up past it
        std::optional<ChainState> view;
        if (im.signal_queue != r.queue) {
            // A record of a third queue: what the signaling queue's log did with it.
            if (foreign_depth >= 4) return true;  // long chains of narrow signals: assume taken in
            ++foreign_depth;
            view = foreign_view(r, queues[im.signal_queue], seg_begin, seg_end);
            --foreign_depth;
            if (!view) return false;
            list = &view->signals;
        }
        for (const SignalMembership& m : *list) {
            if (m.signal == im.signal) {
                *available = m.available;
                return true;
            }
        }
        return false;
    }

    // ------------------------------------------------------------------ hazard decisions
    struct Later {
        const Record* record;
        uint16_t queue;
        bool deserialize;
    };

    // Is `prior` execution-ordered before `later`, and (when `need_visible`) is it visible?
    // Returns the fix to suggest when it is not; nullopt when ordered.
    std::optional<FixKind> unordered(Record& prior, const Later& later, bool need_visible, uint64_t seg_begin,
                                     uint64_t seg_end) {
        const Record& b = *later.record;
        if (prior.queue == kHostSlot) return std::nullopt;  // host work before the submit: ordered and visible
        const bool prior_complete = prior.completed || prior.tag < queues[prior.queue].complete;
        if (later.queue == kHostSlot) {
            if (!prior_complete) return need_visible ? FixKind::kHostWaitAndBarrier : FixKind::kHostWait;
            if (!need_visible || b.is_write) return std::nullopt;
            catch_up(prior, seg_begin, seg_end);
            return prior.sync.visible.covers(VK_PIPELINE_STAGE_2_HOST_BIT, b.atoms)
                       ? std::nullopt
                       : std::optional<FixKind>(FixKind::kHostWaitAndBarrier);
        }
        if (prior_complete) return std::nullopt;
        const ChainState* s = nullptr;
        std::optional<ChainState> foreign;
        if (prior.queue == later.queue) {
            catch_up(prior, seg_begin, seg_end);
            s = &prior.sync;
        } else {
            if (any_narrow) catch_up(prior, seg_begin, seg_end);  // its narrow-signal memberships
            foreign = foreign_view(prior, queues[later.queue], seg_begin, seg_end);
            if (!foreign) return FixKind::kSemaphore;
            s = &*foreign;
        }
        const bool ok = need_visible ? s->visible.covers(b.stage, b.atoms) : (s->chain & b.stage) != 0;
        if (ok) return std::nullopt;
        return prior.queue == later.queue ? FixKind::kPipelineBarrier : FixKind::kSemaphore;
    }

    struct Finding {
        HazardKey key;
        Record prior;  // a copy: the segment's record is replaced right after the check
        FixKind fix;
        AddressRange overlap;
        // The later access is one element of an element run: the element's field and bytes.
        bool later_element = false;
        uint32_t later_field = 0;
        AddressRange later_range;
        uint32_t order = 0;         // record_accesses: index of the later access in the command's list
        uint32_t later_record = 0;  // record_accesses: which of its records was the later access
    };

    // The element of an element run holding byte `at`: its field and bytes (a plain record:
    // its own). Interning here runs only on the hazard path.
    void element_of(const Record& r, uint64_t at, uint32_t* field, AddressRange* range) {
        if (!r.element_bytes) {
            *field = r.field;
            *range = r.range;
            return;
        }
        const uint64_t k = (at - r.range.begin) / r.element_bytes;
        range->begin = r.range.begin + k * r.element_bytes;
        range->end = range->begin + r.element_bytes;
        const std::string name = field_names[r.field] + std::to_string(r.first_element + k) + field_names[r.field_suffix];
        *field = intern(name);
    }

    // Findings of one access are few, except when an element run meets another: then the
    // pairs of elements are many, and a linear search for the key would be quadratic.
    std::unordered_map<HazardKey, std::size_t, HazardKeyHash> found_index;

    void note_one(std::vector<Finding>& found, HazardKey key, const Record& prior, const AddressRange& prior_range,
                  const Record& later, const AddressRange& later_range, FixKind fix, uint64_t begin, uint64_t end) {
        Finding* same = nullptr;
        if (found.size() <= 16) {
            for (Finding& f : found)
                if (f.key == key) same = &f;
        } else {
            if (found_index.empty())
                for (std::size_t i = 0; i < found.size(); ++i) found_index.emplace(found[i].key, i);
            if (auto it = found_index.find(key); it != found_index.end()) same = &found[it->second];
        }
        if (same) {  // the same two accesses over adjacent segments: widen the region
            same->overlap.begin = std::min(same->overlap.begin, begin);
            same->overlap.end = std::max(same->overlap.end, end);
            return;
        }
        Finding f;
        f.key = key;
        f.prior = prior;
        f.fix = fix;
        f.overlap = {begin, end};
        if (prior.element_bytes) {
            f.prior.range = prior_range;
            f.prior.field = key.prior_field;
            f.prior.element_bytes = 0;
        }
        if (later.element_bytes) {
            f.later_element = true;
            f.later_field = key.later_field;
            f.later_range = later_range;
        }
        if (!found_index.empty()) found_index.emplace(key, found.size());
        found.push_back(std::move(f));
    }

    void note(std::vector<Finding>& found, HazardClass hazard, const Record& prior, const Record& later, FixKind fix,
              uint64_t seg_begin, uint64_t seg_end) {
        if (!prior.element_bytes && !later.element_bytes) {
            note_one(found, {prior.tag, later.tag, prior.field, later.field, hazard}, prior, prior.range, later,
                     later.range, fix, seg_begin, seg_end);
            return;
        }
        // Per pair of elements whose bytes meet, in address order: what record_access on
        // each element would have found segment by segment.
        for (uint64_t p = seg_begin; p < seg_end;) {
            uint32_t prior_field;
            AddressRange prior_range;
            element_of(prior, p, &prior_field, &prior_range);
            const uint64_t p_end = std::min(seg_end, prior_range.end);
            for (uint64_t l = p; l < p_end;) {
                uint32_t later_field;
                AddressRange later_range;
                element_of(later, l, &later_field, &later_range);
                const uint64_t l_end = std::min(p_end, later_range.end);
                note_one(found, {prior.tag, later.tag, prior_field, later_field, hazard}, prior, prior_range, later,
                         later_range, fix, l, l_end);
                l = l_end;
            }
            p = p_end;
        }
    }

    HazardAccess describe(const Record& r) const {
        HazardAccess a;
        a.command = r.command;
        a.queue = r.queue == kHostSlot ? kHostQueue : queues[r.queue].id;
        a.stage = r.stage;
        a.access = r.access;
        a.is_write = r.is_write;
        a.range = r.range;
        a.field = field_names[r.field];
        return a;
    }

    void emit(const Finding& f, const Record& later) {
        if (seen.count(f.key)) {
            ++stats.duplicate_hazards;
            return;
        }
        if (reports.size() >= options.max_reports) {
            // Past the cap nothing more is remembered, so memory stays bounded in a stream
            // that is all hazards; repeats are then counted here too.
            ++stats.hazards_over_cap;
            return;
        }
        seen.insert(f.key);
        HazardReport rep;
        rep.hazard = f.key.hazard;
        rep.prior = describe(f.prior);
        rep.later = describe(later);
        if (f.later_element) {
            rep.later.range = f.later_range;
            rep.later.field = field_names[f.later_field];
        }
        rep.overlap = f.overlap;
        rep.fix.kind = f.fix;
        rep.fix.src_stages = f.prior.stage;
        rep.fix.dst_stages = later.stage;
        const bool memory = f.key.hazard != HazardClass::kWriteAfterRead &&
                            !(f.key.hazard == HazardClass::kDeserializeInUse && !f.prior.is_write);
        if (memory) {
            rep.fix.src_access = f.prior.access & (all_write_accesses() | VK_ACCESS_2_SHADER_WRITE_BIT |
                                                    VK_ACCESS_2_MEMORY_WRITE_BIT);
            rep.fix.dst_access = later.access;
        }
        if (f.fix == FixKind::kHostWaitAndBarrier) {
            rep.fix.dst_stages = VK_PIPELINE_STAGE_2_HOST_BIT;
            rep.fix.dst_access = VK_ACCESS_2_HOST_READ_BIT;
        }
        reports.push_back(std::move(rep));
    }

    // ------------------------------------------------------------------ the address map
    // Makes `at` a segment boundary if a segment straddles it.
    void split_at(uint64_t at) { segments.split_at(at); }

    // One pass over the segments [begin, end) touches: splits at the two ends, fills gaps
    // with fresh segments, and (a write) leaves one segment behind, so that overlapping
    // writes do not fragment memory byte by byte.
    // `collect`: findings go there instead of being reported (record_accesses orders them).
    void record(const Record& b, bool deserialize, std::vector<Finding>* collect = nullptr) {
        ++stats.accesses;
        const uint64_t begin = b.range.begin, end = b.range.end;
        if (end <= begin) return;
        std::vector<Finding> found;
        if (!found_index.empty()) found_index.clear();  // clear() would wipe every bucket each time
        const Later later{&b, b.queue, deserialize};
        segments.update(
            begin, end, b.is_write,
            [&](Segment& fresh, uint64_t, uint64_t) {
                if (b.is_write) fresh.write = b;
                else fresh.reads.push_back(b);
            },
            [&](Segment& seg, uint64_t seg_begin, uint64_t seg_end) {
                check_and_update(seg, seg_begin, seg_end, later, found);
            });
        if (collect) collect->insert(collect->end(), std::make_move_iterator(found.begin()), std::make_move_iterator(found.end()));
        else
            for (const Finding& f : found) emit(f, b);
        stats.segments = segments.size();
        stats.peak_segments = std::max<uint64_t>(stats.peak_segments, segments.size());
    }

    void check_and_update(Segment& seg, uint64_t seg_begin, uint64_t seg_end, const Later& later,
                          std::vector<Finding>& found) {
        const Record& b = *later.record;
        if (b.is_write) {
            bool any_read = false;
            for (Record& r : seg.reads) {
                if (r.tag == b.tag) continue;
                // A read the host saw complete orders nothing and hides nothing: sweeps drop
                // such reads lazily, so they must count as already gone.
                if (r.queue != kHostSlot && r.tag < queues[r.queue].complete) continue;
                any_read = true;
                if (auto fix = unordered(r, later, false, seg_begin, seg_end))
                    note(found, later.deserialize ? HazardClass::kDeserializeInUse : HazardClass::kWriteAfterRead, r,
                         b, *fix, seg_begin, seg_end);
            }
            if (!any_read && seg.write && seg.write->tag != b.tag) {
                if (auto fix = unordered(*seg.write, later, true, seg_begin, seg_end))
                    note(found, later.deserialize ? HazardClass::kDeserializeInUse : HazardClass::kWriteAfterWrite,
                         *seg.write, b, *fix, seg_begin, seg_end);
            }
            seg.write = b;
            seg.reads.clear();
            return;
        }
        if (seg.write && seg.write->tag != b.tag) {
            if (auto fix = unordered(*seg.write, later, true, seg_begin, seg_end))
                note(found, HazardClass::kReadAfterWrite, *seg.write, b, *fix, seg_begin, seg_end);
        }
        // A host read is over when the call returns: it orders itself before all later work
        // and must not stand between the write and later writes.
        if (b.queue == kHostSlot) return;
        for (Record& r : seg.reads) {
            if (r.queue == b.queue && r.stage == b.stage) {
                r = b;  // a later read on the same queue and stage is ordered by whatever orders this one
                return;
            }
        }
        seg.reads.push_back(b);
    }

    Record make_record(const CommandRef& command, const Access& a, uint16_t queue, uint64_t t) {
        Record r;
        fill_record(r, command, a, queue, t);
        return r;
    }
    // make_record into an existing record (record_accesses reuses one, sparing its vectors).
    void fill_record(Record& r, const CommandRef& command, const Access& a, uint16_t queue, uint64_t t) {
        fill_record(r, command, a, queue, t, intern(a.field));
    }
    void fill_record(Record& r, const CommandRef& command, const Access& a, uint16_t queue, uint64_t t,
                     uint32_t field) {
        r.element_bytes = 0;
        r.first_element = 0;
        r.field_suffix = 0;
        r.completed = false;
        r.sync.chain = 0;
        r.sync.avail = 0;
        r.sync.visible.clear();
        r.sync.signals.clear();
        r.tag = t;
        r.command = command;
        r.range = a.range;
        r.stage = atomic_stages(a.stage) & ~kEventStageBits;
        r.access = a.access;
        r.atoms = atomic_accesses(a.access);
        r.is_write = a.is_write;
        r.field = field;
        r.queue = queue;
        r.log_pos = queue == kHostSlot ? 0 : queues[queue].log_end();
    }

    // ------------------------------------------------------------------ barriers
    uint32_t pool_barriers(Queue& q, const DependencyInfo& dep) {
        const uint32_t first = q.pool_base + uint32_t(q.pool.size());
        for (const MemoryBarrier& m : dep.memory_barriers) {
            q.pool.push_back({source_scope_of(m.src_stages), destination_scope_of(m.dst_stages),
                              atomic_accesses(m.src_access), atomic_accesses(m.dst_access), {}, true});
        }
        for (const BufferBarrier& bb : dep.buffer_barriers) {
            if (bb.range.empty()) continue;
            q.pool.push_back({source_scope_of(bb.masks.src_stages), destination_scope_of(bb.masks.dst_stages),
                              atomic_accesses(bb.masks.src_access), atomic_accesses(bb.masks.dst_access), bb.range,
                              false});
            // Segments must lie wholly inside or outside every buffer barrier's range.
            split_at(bb.range.begin);
            split_at(bb.range.end);
        }
        stats.barriers += dep.memory_barriers.size() + dep.buffer_barriers.size();
        return first;
    }

    void log_barrier_entry(EntryKind kind, const DependencyInfo& dep, StageMask event_bits, bool v1) {
        Queue& q = queues[current_queue];
        LogEntry e;
        e.kind = kind;
        e.first = pool_barriers(q, dep);
        e.count = q.pool_base + uint32_t(q.pool.size()) - e.first;
        e.event_bits = event_bits;
        e.v1_event = v1;
        if (e.count == 0 && kind == EntryKind::kBarrier) return;
        const StageMask device = all_device_stages();
        const AccessMask all = all_read_accesses() | all_write_accesses();
        bool special = kind == EntryKind::kEventSet, full = false;
        for (uint32_t i = 0; i < e.count; ++i) {
            const LoggedBarrier& b = q.pool[e.first + i - q.pool_base];
            special = special || (b.dst_scope & ~device);
            full = full || (kind == EntryKind::kBarrier && b.global && (b.src_scope & device) == device &&
                            (b.dst_scope & device) == device && (b.src_atoms & all_write_accesses()) == all_write_accesses() &&
                            (b.dst_atoms & all) == all);
        }
        const uint32_t pos = q.log_end();
        e.run_start = pos;
        e.run_end = pos + 1;
        if (special) {
            q.special_positions.push_back(pos);
        } else if (full) {
            q.full_positions.push_back(pos);
        } else if (kind == EntryKind::kBarrier && e.count == 1 && !q.log.empty()) {
            const LogEntry& prev = q.log.back();
            if (prev.kind == EntryKind::kBarrier && prev.count == 1 && prev.run_end == pos &&
                same_barrier(q.pool[prev.first - q.pool_base], q.pool[e.first - q.pool_base])) {
                q.pool.pop_back();  // share the run's pooled barrier
                e.first = prev.first;
                e.run_start = prev.run_start;
                q.log[prev.run_start - q.log_base].run_end = pos + 1;
            }
        }
        if (e.run_start == pos && !(kind == EntryKind::kBarrier && e.count == 1 && !special && !full))
            e.run_start = kNoRun;  // not a run member: catch-up never skips past it
        q.log.push_back(e);
        maybe_compact(q);
    }

    // ------------------------------------------------------------------ host waits
    // Accesses older than a queue's `complete` count as finished wherever they are met, so
    // dropping them (retire) only saves memory. A sweep costs a pass over every segment, so
    // fence and semaphore waits sweep only once the segments have doubled since the last
    // sweep (memory stays within twice what is live, plus kSweepFloor); idle waits always do.
    static constexpr std::size_t kSweepFloor = 1024;
    std::size_t sweep_at = kSweepFloor;

    void complete_through(const Clock& clock, bool always_sweep) {
        for (std::size_t i = 0; i < queues.size() && i < clock.size(); ++i)
            queues[i].complete = std::max(queues[i].complete, clock[i]);
        if (!always_sweep && segments.size() < sweep_at) return;
        retire();
        prune_timelines();
        sweep_at = std::max(kSweepFloor, 2 * segments.size());
    }

    bool all_complete(const Clock& c) const {
        for (std::size_t i = 0; i < c.size() && i < queues.size(); ++i)
            if (c[i] > queues[i].complete) return false;
        return true;
    }

    // A timeline semaphore keeps one clock per value signalled, so an app counting frames
    // on it would grow the map with the trace. A value whose signal and next value's signal
    // are both complete can go: a wait on it finds that next value, whose extra coverage is
    // completed work, which orders nothing any more.
    void prune_timelines() {
        for (auto& [handle, sem] : semaphores) {
            auto& timeline = sem.timeline;
            for (auto it = timeline.begin(); it != timeline.end();) {
                auto next = std::next(it);
                if (next != timeline.end() && all_complete(it->second) && all_complete(next->second)) it = timeline.erase(it);
                else it = next;
            }
        }
    }

    // Drops what host waits proved finished; keeps completed writes the host cannot see yet.
    void retire() {
        segments.erase_if([&](Segment& seg, uint64_t seg_begin, uint64_t seg_end) {
            std::erase_if(seg.reads, [&](const Record& r) {
                return r.queue == kHostSlot || r.tag < queues[r.queue].complete;
            });
            if (seg.write) {
                Record& w = *seg.write;
                if (w.queue == kHostSlot) {
                    seg.write.reset();
                } else if (!w.completed && w.tag < queues[w.queue].complete) {
                    catch_up(w, seg_begin, seg_end);
                    if (w.sync.visible.covers(VK_PIPELINE_STAGE_2_HOST_BIT, VK_ACCESS_2_HOST_READ_BIT))
                        seg.write.reset();
                    else
                        w.completed = true;
                }
            }
            return !seg.write && seg.reads.empty();
        });
        trim_logs();
        for (Queue& q : queues) q.log_size_after_trim = q.log.size();
        stats.segments = segments.size();
    }

    // Forgets log entries no live record can still need.
    void trim_logs() {
        std::vector<uint32_t> keep(queues.size());
        for (std::size_t i = 0; i < queues.size(); ++i) keep[i] = queues[i].log_end();
        auto need = [&](const Record& r) {
            if (r.queue == kHostSlot || r.completed) return;
            keep[r.queue] = std::min(keep[r.queue], r.log_pos);
            for (std::size_t w = 0; w < queues.size(); ++w) {
                if (w == r.queue) continue;
                const auto& ims = queues[w].imports;
                auto it = std::partition_point(ims.begin(), ims.end(), [&](const Import& im) {
                    return covered(im.cumulative, r.queue) <= r.tag;
                });
                if (it != ims.end()) keep[w] = std::min(keep[w], it->log_pos);
            }
        };
        segments.for_each([&](const Segment& seg, uint64_t, uint64_t) {
            if (seg.write) need(*seg.write);
            for (const Record& r : seg.reads) need(r);
        });
        for (std::size_t i = 0; i < queues.size(); ++i) {
            Queue& q = queues[i];
            const uint32_t drop = keep[i] - q.log_base;
            if (drop == 0) continue;
            // Barriers and imports referenced by the kept entries stay.
            uint32_t pool_keep = q.pool_base + uint32_t(q.pool.size());
            uint32_t import_keep = q.imports_base + uint32_t(q.imports.size());
            for (uint32_t k = drop; k < q.log.size(); ++k) {
                const LogEntry& e = q.log[k];
                if (e.kind == EntryKind::kImport) import_keep = std::min(import_keep, e.import_index);
                else pool_keep = std::min(pool_keep, e.first);
            }
            if (drop < q.log.size()) {
                // A run cut by the trim gets its first kept entry as new head.
                const uint32_t head = q.log[drop].run_start;
                if (head != kNoRun && head < keep[i]) {
                    const uint32_t end = q.log[head - q.log_base].run_end;
                    for (std::size_t k = drop; k < q.log.size() && q.log[k].run_start == head; ++k)
                        q.log[k].run_start = keep[i];
                    q.log[drop].run_end = end;
                }
            }
            q.log.erase(q.log.begin(), q.log.begin() + drop);
            q.log_base += drop;
            std::erase_if(q.full_positions, [&](uint32_t p) { return p < q.log_base; });
            std::erase_if(q.special_positions, [&](uint32_t p) { return p < q.log_base; });
            q.pool.erase(q.pool.begin(), q.pool.begin() + (pool_keep - q.pool_base));
            q.pool_base = pool_keep;
            // Imports also serve the binary search; only those wholly before the kept log go.
            uint32_t import_drop = 0;
            while (import_drop < q.imports.size() && q.imports_base + import_drop < import_keep &&
                   q.imports[import_drop].log_pos < q.log_base)
                ++import_drop;
            q.imports.erase(q.imports.begin(), q.imports.begin() + import_drop);
            q.imports_base += import_drop;
        }
    }

    // Without host waits the log would grow with the trace: now and then bring every record
    // up to date and drop what none needs. Doubling keeps the cost amortized.
    void maybe_compact(const Queue& q) {
        if (q.log.size() > 4096 && q.log.size() > 2 * q.log_size_after_trim) compact();
    }

    void compact() {
        segments.for_each([&](Segment& seg, uint64_t begin, uint64_t end) {
            if (seg.write) catch_up(*seg.write, begin, end);
            for (Record& r : seg.reads) catch_up(r, begin, end);
        });
        trim_logs();
        for (Queue& q : queues) q.log_size_after_trim = q.log.size();
    }

    Clock snapshot_now(uint16_t slot) {
        Clock c = queues[slot].known;
        c[slot] = tag + 1;
        return c;
    }
};

// ====================================================================== public API

SyncModel::SyncModel(SyncOptions options) : state_(std::make_unique<State>()) {
    state_->options = options;
    state_->intern("");  // id 0: no field
}
SyncModel::~SyncModel() = default;

void SyncModel::begin_submission(QueueId queue, uint32_t, std::span<const SemaphoreWait> waits) {
    State& s = *state_;
    s.current_queue = s.queue_slot(queue);
    s.in_submission = true;
    s.sync_tag();
    for (const SemaphoreWait& w : waits) {
        SemaphoreState& sem = s.semaphores[w.semaphore];
        std::optional<Clock> clock;
        NarrowSignal narrow;
        if (sem.binary_signal) {
            clock = std::move(sem.binary_signal);
            sem.binary_signal.reset();  // a binary wait consumes the signal
            narrow = sem.binary_narrow;
            sem.binary_narrow = {};
        } else if (auto it = sem.timeline.lower_bound(w.value); it != sem.timeline.end()) {
            clock = it->second;
            if (auto n = sem.timeline_narrow.find(it->first); n != sem.timeline_narrow.end()) narrow = n->second;
        }
        if (!clock) {
            ++s.stats.unsatisfied_waits;
            continue;
        }
        clock->resize(s.queues.size(), 0);
        Queue& q = s.queues[s.current_queue];
        for (std::size_t i = 0; i < q.known.size(); ++i) q.known[i] = std::max(q.known[i], (*clock)[i]);
        Import im;
        im.log_pos = q.log_end();
        im.own = std::move(*clock);
        im.cumulative = q.known;
        // VUID-VkSubmitInfo-pWaitDstStageMask-00078: waits never name HOST; keep device stages.
        im.dst_scope = destination_scope_of(w.dst_stages) & kDeviceStages;
        im.signal = narrow.signal;
        im.signal_queue = narrow.queue;
        LogEntry e;
        e.kind = EntryKind::kImport;
        e.import_index = q.imports_base + uint32_t(q.imports.size());
        q.imports.push_back(std::move(im));
        q.log.push_back(e);
        ++s.stats.barriers;
    }
}

void SyncModel::record_access(const CommandRef& command, const Access& access) {
    State& s = *state_;
    const uint64_t t = s.command_tag(command, s.current_queue);
    s.record(s.make_record(command, access, s.current_queue, t), false);
}


void SyncModel::record_accesses(const CommandRef& command, std::span<const Access> accesses) {
    State& s = *state_;
    const std::size_t n = accesses.size();
    if (n < 2) {
        for (const Access& a : accesses) record_access(command, a);
        return;
    }
    const uint64_t t = s.command_tag(command, s.current_queue);

    // Accesses overlapping another of the command keep their place in the order: pinned.
    auto& by_begin = s.batch.by_begin;
    by_begin.clear();
    // Sorted as one 64-bit key (begin above the index) where both fit: the same order as the
    // pairs at a fraction of the comparisons' cost, which showed in the profile.
    constexpr int kIndexBits = 20;
    auto& packed = s.batch.packed;
    packed.clear();
    bool fits = n < (std::size_t(1) << kIndexBits);
    for (uint32_t i = 0; i < n && fits; ++i) {
        const AddressRange& r = accesses[i].range;
        if (r.empty()) continue;
        fits = r.begin < (uint64_t(1) << (64 - kIndexBits));
        packed.push_back(r.begin << kIndexBits | i);
    }
    if (fits) {
        std::sort(packed.begin(), packed.end());
        for (uint64_t k : packed) by_begin.push_back({k >> kIndexBits, uint32_t(k & ((1u << kIndexBits) - 1))});
    } else {
        for (uint32_t i = 0; i < n; ++i)
            if (!accesses[i].range.empty()) by_begin.push_back({accesses[i].range.begin, i});
        std::sort(by_begin.begin(), by_begin.end());
    }
    auto& pinned = s.batch.pinned;
    pinned.assign(n, 0);
    uint64_t reach = 0;
    uint32_t reach_index = 0;
    bool any = false;
    for (const auto& [begin, i] : by_begin) {
        if (any && begin < reach) pinned[i] = pinned[reach_index] = 1;
        if (!any || accesses[i].range.end > reach) {
            reach = accesses[i].range.end;
            reach_index = i;
            any = true;
        }
    }

    // Each access's field, interned once for the run forming below and its record.
    auto& field_of = s.batch.field_of;
    field_of.resize(n);
    for (uint32_t i = 0; i < n; ++i) field_of[i] = s.intern(accesses[i].field);

    // Element runs, each growing while the next element continues it.
    using Run = State::Run;
    auto& runs = s.batch.runs;
    runs.clear();
    auto& run_of = s.batch.run_of;
    auto& next_member = s.batch.next_member;
    run_of.assign(n, -1);
    next_member.assign(n, -1);
    std::size_t open[8];  // runs still growing, one per field shape
    std::size_t open_count = 0;
    for (uint32_t i = 0; i < n; ++i) {
        const Access& a = accesses[i];
        if (pinned[i] || a.range.empty()) continue;
        const State::FieldShape shape = s.field_shapes[field_of[i]];
        if (!shape.indexed) continue;
        const uint32_t prefix = shape.prefix, suffix = shape.suffix;
        const uint64_t index = shape.index;
        const uint64_t bytes = a.range.end - a.range.begin;
        std::size_t* slot = nullptr;
        for (std::size_t k = 0; k < open_count; ++k) {
            const Run& r = runs[open[k]];
            const Access& h = accesses[r.head];
            if (r.prefix == prefix && r.suffix == suffix && h.stage == a.stage && h.access == a.access &&
                h.is_write == a.is_write)
                slot = &open[k];
        }
        if (slot) {
            Run& r = runs[*slot];
            if (r.next == index && r.range.end == a.range.begin && r.bytes == bytes) {
                r.range.end = a.range.end;
                ++r.next;
                next_member[r.last] = int32_t(i);
                r.last = i;
                ++r.count;
                run_of[i] = int32_t(*slot);
                continue;
            }
        }
        if (bytes > UINT32_MAX || index > UINT32_MAX) continue;
        runs.push_back({prefix, suffix, index, index + 1, bytes, a.range, i, i});
        run_of[i] = int32_t(runs.size() - 1);
        if (slot) *slot = runs.size() - 1;
        else if (open_count < std::size(open)) open[open_count++] = runs.size() - 1;
    }
    // Each run's members in one flat list: a finding on element k belongs to its k-th access.
    auto& members = s.batch.members;
    members.clear();
    for (Run& r : runs) {
        r.members_at = uint32_t(members.size());
        for (int32_t m = int32_t(r.head); m >= 0; m = next_member[std::size_t(m)]) members.push_back(uint32_t(m));
    }

    // Record in the command's order (a run at its first element); report in that order too.
    std::vector<State::Finding> found, each;
    std::vector<Record> laters;
    for (uint32_t i = 0; i < n; ++i) {
        const int32_t ri = run_of[i];
        const Run* run = ri >= 0 && runs[std::size_t(ri)].count > 1 ? &runs[std::size_t(ri)] : nullptr;
        if (run && run->head != i) continue;
        Record& rec = s.batch.record;
        if (run) {
            Access a = accesses[i];
            a.range = run->range;
            s.fill_record(rec, command, a, s.current_queue, t, run->prefix);
            rec.element_bytes = uint32_t(run->bytes);
            rec.first_element = uint32_t(run->first);
            rec.field_suffix = run->suffix;
            s.stats.accesses += run->count - 1;  // counted per access, as record_access would
        } else {
            s.fill_record(rec, command, accesses[i], s.current_queue, t, field_of[i]);
        }
        each.clear();
        s.record(rec, false, &each);
        if (each.empty()) continue;
        for (State::Finding& f : each) {
            f.order = i;
            if (f.later_element)
                f.order = members[run->members_at + std::size_t((f.later_range.begin - rec.range.begin) / rec.element_bytes)];
            f.later_record = uint32_t(laters.size());
        }
        laters.push_back(rec);
        found.insert(found.end(), std::make_move_iterator(each.begin()), std::make_move_iterator(each.end()));
    }
    std::stable_sort(found.begin(), found.end(),
                     [](const State::Finding& a, const State::Finding& b) { return a.order < b.order; });
    for (const State::Finding& f : found) s.emit(f, laters[f.later_record]);
}

void SyncModel::record_copy(const CommandRef& command, const Access& source, const Access& destination) {
    State& s = *state_;
    const uint64_t t = s.command_tag(command, s.current_queue);
    Record src = s.make_record(command, source, s.current_queue, t);
    Record dst = s.make_record(command, destination, s.current_queue, t);
    if (source.range.overlaps(destination.range)) {
        State::Finding f;
        f.key = {t, t, src.field, dst.field, HazardClass::kMoveOverlap};
        f.prior = src;
        f.fix = FixKind::kDisjointRanges;
        f.overlap = {std::max(source.range.begin, destination.range.begin),
                     std::min(source.range.end, destination.range.end)};
        s.emit(f, dst);
    }
    s.record(src, false);
    s.record(dst, false);
}

void SyncModel::record_deserialize(const CommandRef& command, const Access& source, const Access& destination) {
    State& s = *state_;
    const uint64_t t = s.command_tag(command, s.current_queue);
    s.record(s.make_record(command, source, s.current_queue, t), false);
    s.record(s.make_record(command, destination, s.current_queue, t), true);
}

void SyncModel::pipeline_barrier(const CommandRef&, const DependencyInfo& dependency) {
    State& s = *state_;
    s.sync_tag();
    s.log_barrier_entry(EntryKind::kBarrier, dependency, 0, false);
}

void SyncModel::set_event(const CommandRef&, uint64_t event, const DependencyInfo& dependency) {
    State& s = *state_;
    s.sync_tag();
    EventState& ev = s.events[event];
    if (ev.slot < 0) {
        const int slot = s.next_slot;
        s.next_slot = (s.next_slot + 1) % kEventSlots;
        if (s.slot_used[std::size_t(slot)]) {
            ++s.stats.event_slot_reuses;
            s.events[s.slot_owner[std::size_t(slot)]].slot = -1;
        }
        s.slot_used[std::size_t(slot)] = true;
        s.slot_owner[std::size_t(slot)] = event;
        ev.slot = slot;
    }
    ev.set_serial = ++s.set_serial;
    ev.v1 = false;
    s.log_barrier_entry(EntryKind::kEventSet, dependency, StageMask(1) << (kFirstEventBit + ev.slot), false);
}

void SyncModel::set_event_v1(const CommandRef& command, uint64_t event, VkPipelineStageFlags stages) {
    const MemoryBarrier b = memory_barrier_v1(stages, 0, 0, 0);
    set_event(command, event, DependencyInfo{std::span(&b, 1), {}, 0});
    Queue& q = state_->queues[state_->current_queue];
    q.log.back().v1_event = true;
    state_->events[event].v1 = true;
}

void SyncModel::reset_event(const CommandRef&, uint64_t event) {
    State& s = *state_;
    s.sync_tag();
    auto it = s.events.find(event);
    if (it == s.events.end() || it->second.slot < 0) return;
    s.slot_used[std::size_t(it->second.slot)] = false;
    it->second.slot = -1;
}

void SyncModel::wait_events(const CommandRef&, std::span<const uint64_t> events, const DependencyInfo& dependency) {
    State& s = *state_;
    s.sync_tag();
    StageMask bits = 0;
    bool v1 = false;
    for (uint64_t event : events) {
        auto it = s.events.find(event);
        if (it == s.events.end() || it->second.slot < 0) continue;  // never set on the device: orders nothing
        bits |= StageMask(1) << (kFirstEventBit + it->second.slot);
        v1 = v1 || it->second.v1;
    }
    if (!bits) return;
    s.log_barrier_entry(EntryKind::kEventWait, dependency, bits, v1);
}

void SyncModel::end_submission(std::span<const SemaphoreSignal> signals, uint64_t fence) {
    State& s = *state_;
    s.sync_tag();
    const Clock clock = s.snapshot_now(s.current_queue);
    for (const SemaphoreSignal& sig : signals) {
        NarrowSignal narrow;
        const StageMask scope = source_scope_of(sig.src_stages) & kDeviceStages;
        if (scope != kDeviceStages) {
            // A mark in the log: catching a record up over it tells whether this signal's
            // first scope (its stages, or a chain into them) took the record in.
            narrow = {++s.next_signal, s.current_queue};
            s.any_narrow = true;
            Queue& q = s.queues[s.current_queue];
            LogEntry e;
            e.kind = EntryKind::kSignal;
            e.event_bits = scope;
            e.signal = narrow.signal;
            e.first = q.pool_base + uint32_t(q.pool.size());  // no barriers: keeps the pool trim valid
            q.special_positions.push_back(q.log_end());
            q.log.push_back(e);
        }
        SemaphoreState& sem = s.semaphores[sig.semaphore];
        if (sig.value == 0) {
            sem.binary_signal = clock;
            sem.binary_narrow = narrow;
        } else {
            sem.timeline[sig.value] = clock;
            if (narrow.signal) sem.timeline_narrow[sig.value] = narrow;
            else sem.timeline_narrow.erase(sig.value);
        }
    }
    if (fence) s.fences[fence] = clock;
    s.in_submission = false;
    s.maybe_compact(s.queues[s.current_queue]);
}

void SyncModel::host_access(const CommandRef& command, const Access& access) {
    State& s = *state_;
    Access a = access;
    a.stage = VK_PIPELINE_STAGE_2_HOST_BIT;
    a.access = a.is_write ? VK_ACCESS_2_HOST_WRITE_BIT : VK_ACCESS_2_HOST_READ_BIT;
    const uint64_t t = s.command_tag(command, kHostSlot);
    s.record(s.make_record(command, a, kHostSlot, t), false);
}

void SyncModel::wait_for_fence(uint64_t fence) {
    State& s = *state_;
    s.sync_tag();
    auto it = s.fences.find(fence);
    if (it == s.fences.end()) return;
    s.complete_through(it->second, false);
}

void SyncModel::queue_wait_idle(QueueId queue) {
    State& s = *state_;
    s.sync_tag();
    const uint16_t slot = s.queue_slot(queue);
    s.complete_through(s.snapshot_now(slot), true);
}

void SyncModel::device_wait_idle() {
    State& s = *state_;
    s.sync_tag();
    Clock all(s.queues.size(), s.tag + 1);
    s.complete_through(all, true);
}

void SyncModel::memory_freed(AddressRange range) {
    State& s = *state_;
    // Completed accesses to freed memory can order nothing any more; the host kept
    // completed writes only for its own later reads, which freed memory cannot have.
    // Accesses still in flight stay: memory freed and reused under them is a hazard.
    s.segments.erase_if(
        [&](Segment& seg, uint64_t seg_begin, uint64_t seg_end) {
            if (seg_begin < range.begin || seg_end > range.end) return false;
            std::erase_if(seg.reads, [&](const Record& r) {
                return r.queue == kHostSlot || r.tag < s.queues[r.queue].complete;
            });
            if (seg.write && (seg.write->queue == kHostSlot || seg.write->completed ||
                              seg.write->tag < s.queues[seg.write->queue].complete))
                seg.write.reset();
            return !seg.write && seg.reads.empty();
        },
        range.begin, range.end);
    s.stats.segments = s.segments.size();
}

void SyncModel::host_wait_semaphore(uint64_t semaphore, uint64_t value) {
    State& s = *state_;
    s.sync_tag();
    auto sem = s.semaphores.find(semaphore);
    if (sem == s.semaphores.end()) return;
    auto it = sem->second.timeline.lower_bound(value);
    if (it == sem->second.timeline.end()) return;
    s.complete_through(it->second, false);
}

void SyncModel::host_signal_semaphore(uint64_t semaphore, uint64_t value) {
    State& s = *state_;
    s.sync_tag();
    s.semaphores[semaphore].timeline[value] = Clock(s.queues.size(), 0);
}

void SyncModel::present_wait(std::span<const uint64_t> semaphores) {
    State& s = *state_;
    for (uint64_t semaphore : semaphores) {
        auto sem = s.semaphores.find(semaphore);
        if (sem == s.semaphores.end()) continue;  // signalled outside the trace (another frame range)
        sem->second.binary_signal.reset();
        sem->second.binary_narrow = {};
    }
}

void SyncModel::acquire_signal(uint64_t semaphore, uint64_t fence) {
    State& s = *state_;
    s.sync_tag();
    if (semaphore) {
        SemaphoreState& sem = s.semaphores[semaphore];
        sem.binary_signal = Clock(s.queues.size(), 0);
        sem.binary_narrow = {};
    }
    if (fence) s.fences[fence] = Clock(s.queues.size(), 0);
}

const std::vector<HazardReport>& SyncModel::hazards() const { return state_->reports; }
const SyncStats& SyncModel::stats() const { return state_->stats; }

std::size_t SyncModel::memory_bytes() const {
    const State& s = *state_;
    std::size_t bytes = s.segments.memory_bytes([](const Segment& seg) { return seg.reads.capacity() * sizeof(Record); });
    for (const Queue& q : s.queues) {
        bytes += q.log.capacity() * sizeof(LogEntry) + q.pool.capacity() * sizeof(LoggedBarrier);
        for (const Import& im : q.imports) bytes += sizeof(Import) + (im.own.size() + im.cumulative.size()) * 8;
    }
    return bytes;
}

}  // namespace clastrace::replay
