// SPDX-License-Identifier: Apache-2.0
#include "clastrace/analyze/analyzer.h"

#include <algorithm>
#include <deque>
#include <map>
#include <tuple>
#include <unordered_map>

#include <fmt/format.h>

#include "address_owners.h"

namespace clastrace::analyze {

namespace {

struct PendingOverlap {
    AddressOwner older;
    uint64_t newer_region = 0;
    RegionRole newer_role = RegionRole::kOther;
    uint64_t base = 0, size = 0;
    OverlapKind kind = OverlapKind::kReuse;
};

using SummaryKey = std::tuple<int, int, int, bool>;

bool is_object_role(RegionRole r) {
    return r == RegionRole::kObjectClas || r == RegionRole::kObjectTemplate ||
           r == RegionRole::kObjectBlas;
}

// Objects of an implicit build live inside that build's dstImplicitData by design.
bool contained_by_design(RegionRole a, RegionRole b) {
    return (a == RegionRole::kImplicitData && is_object_role(b)) ||
           (b == RegionRole::kImplicitData && is_object_role(a));
}

bool ranges_intersect(uint64_t a, uint64_t as, uint64_t b, uint64_t bs) {
    return a < b + bs && b < a + as;
}

// The N most expensive commands by one clock, kept in a heap whose top is evicted first.
class TopCommands {
public:
    explicit TopCommands(std::optional<uint64_t> CommandRow::*clock) : clock_(clock) {}
    void offer(const CommandRow& c, std::size_t n) {
        if (n == 0 || !(c.*clock_)) return;
        if (heap_.size() < n) {
            heap_.push_back(c);
            std::push_heap(heap_.begin(), heap_.end(), order());
        } else if (order()(c, heap_.front())) {
            std::pop_heap(heap_.begin(), heap_.end(), order());
            heap_.back() = c;
            std::push_heap(heap_.begin(), heap_.end(), order());
        }
    }
    std::vector<CommandRow> sorted() const {
        std::vector<CommandRow> v = heap_;
        std::sort(v.begin(), v.end(), order());
        return v;
    }

private:
    // Costlier first; equal cost: earlier command first.
    struct Order {
        std::optional<uint64_t> CommandRow::*clock;
        bool operator()(const CommandRow& a, const CommandRow& b) const {
            uint64_t ca = *(a.*clock), cb = *(b.*clock);
            return ca != cb ? ca > cb : a.ordinal < b.ordinal;
        }
    };
    Order order() const { return Order{clock_}; }
    std::optional<uint64_t> CommandRow::*clock_;
    std::vector<CommandRow> heap_;
};

}  // namespace

struct Analyzer::State {
    AnalyzerLimits limits;
    AnalysisReport report;
    bool finished = false;

    // The open command.
    bool open = false;
    CommandRow current;
    std::optional<BuildSizesInfo> current_query;
    uint64_t current_implicit_used = 0;
    bool implicit_allocated_given = false, scratch_allocated_given = false;
    std::optional<uint64_t> implicit_used_given;
    uint64_t current_driver_object_bytes = 0;
    uint64_t submission_commands = 0, submission_ops = 0;  // of the submission being fed
    std::unordered_map<std::string, std::size_t> kind_index;
    std::vector<PendingOverlap> pending_overlaps;
    std::vector<HazardSummary> pending_hazards;

    uint64_t last_submission = 0;
    std::array<TruncationRow, 33> truncation{};

    std::unordered_map<uint64_t, RegionRow> regions;
    AddressOwners owners;
    std::vector<OwnerOverlap> taken;  // scratch buffer for paint()

    std::map<std::pair<uint64_t, uint64_t>, std::size_t> overlap_index;
    std::size_t hazard_pairs_past_cap = 0;
    std::map<SummaryKey, OverlapSummaryRow> summary;

    std::deque<CommandRow> recent;
    TopCommands top_gpu{&CommandRow::gpu_ns};
    TopCommands top_replay{&CommandRow::replay_ns};
    uint64_t timeline_width = 1;  // commands per bucket

    void require_open(const char* event) const {
        if (!open)
            throw AnalysisInputError(
                fmt::format("{} before any on_command: every event belongs to a command", event));
    }

    void close_command();
    void add_command_sizes();
    std::vector<uint64_t> meet_overlaps_with_hazards();
    int hazard_of(const PendingOverlap& p) const;
    void add_to_summary(const PendingOverlap& p, bool hazard);
    OverlapRow* overlap_row_for(const PendingOverlap& p, bool hazard);
    OverlapRow new_overlap_row(const PendingOverlap& p) const;
    void list_hazards(const std::vector<uint64_t>& hazard_matches);
    void add_to_timeline(const CommandRow& c);
    void add_to_kinds(const CommandRow& c);
    void list_command(const CommandRow& c);
    const CommandRow* find_recent(uint64_t ordinal) const {
        for (const auto& r : recent)
            if (r.ordinal == ordinal) return &r;
        return nullptr;
    }
};

Analyzer::Analyzer(std::string trace_name, AnalyzerLimits limits)
    : state_(std::make_unique<State>()) {
    // A timeline of zero buckets could not merge its way back under its cap.
    if (limits.timeline_buckets == 0) limits.timeline_buckets = 1;
    state_->limits = limits;
    state_->report.trace_name = std::move(trace_name);
    for (int i = 0; i < kOpTypeCount; ++i)
        state_->report.by_op_type[i].op_type = static_cast<OpType>(i);
}

Analyzer::~Analyzer() = default;

void Analyzer::on_command(const CommandInfo& c) {
    State& s = *state_;
    if (s.finished) throw AnalysisInputError("on_command after finish()");
    if (static_cast<int>(c.op_type) >= kOpTypeCount)
        throw AnalysisInputError(fmt::format("command {}: op_type {} is not a known op type",
                                             c.ordinal, static_cast<int>(c.op_type)));
    if (static_cast<int>(c.op_mode) > static_cast<int>(OpMode::kNone))
        throw AnalysisInputError(fmt::format("command {}: op_mode {} is not a known op mode",
                                             c.ordinal, static_cast<int>(c.op_mode)));
    if (s.open || s.report.commands > 0) {
        uint64_t prev = s.open ? s.current.ordinal : 0;
        if (c.ordinal <= prev)
            throw AnalysisInputError(fmt::format(
                "command ordinal {} follows ordinal {}: ordinals must strictly increase", c.ordinal,
                prev));
        if (c.submission < s.last_submission)
            throw AnalysisInputError(
                fmt::format("command {}: submission {} follows submission {}: submissions "
                            "must not decrease",
                            c.ordinal, c.submission, s.last_submission));
    }
    if (s.open) s.close_command();

    AnalysisReport& r = s.report;
    if (r.commands == 0 || c.submission != s.last_submission) {
        ++r.submissions;
        s.submission_commands = s.submission_ops = 0;
    }
    ++s.submission_commands;
    s.submission_ops += c.op_count;
    // Largest: most ops, then most commands, then first.
    const bool same = r.largest_submission == c.submission && r.largest_submission_commands > 0;
    if (same || s.submission_ops > r.largest_submission_ops ||
        (s.submission_ops == r.largest_submission_ops &&
         s.submission_commands > r.largest_submission_commands)) {
        r.largest_submission = c.submission;
        r.largest_submission_ops = s.submission_ops;
        r.largest_submission_commands = s.submission_commands;
    }
    s.last_submission = c.submission;
    ++r.commands;
    r.ops += c.op_count;
    r.triangles += c.triangles;

    OpTypeSizes& t = r.by_op_type[static_cast<int>(c.op_type)];
    ++t.commands;
    t.ops += c.op_count;
    if (c.replay_ns) {
        r.replay_timing_present = true;
        t.replay_ns += *c.replay_ns;
        t.replay_ops += c.op_count;
        t.replay_triangles += c.triangles;
    }
    if (c.gpu_ns) {
        r.gpu_timing_present = true;
        t.gpu_ns += *c.gpu_ns;
        t.gpu_ops += c.op_count;
        t.gpu_triangles += c.triangles;
        ++t.gpu_commands;
    }

    s.open = true;
    s.current = CommandRow{};
    CommandRow& row = s.current;
    row.ordinal = c.ordinal;
    row.submission = c.submission;
    row.command_buffer = c.command_buffer;
    row.index = c.index;
    row.name = c.name;
    row.op_type = c.op_type;
    row.op_mode = c.op_mode;
    row.op_count = c.op_count;
    row.triangles = c.triangles;
    row.gpu_ns = c.gpu_ns;
    row.replay_ns = c.replay_ns;
    row.scratch_used = c.scratch_used_bytes;
    s.implicit_allocated_given = c.implicit_allocated_bytes.has_value();
    s.scratch_allocated_given = c.scratch_allocated_bytes.has_value();
    row.implicit_allocated = c.implicit_allocated_bytes.value_or(0);
    row.scratch_allocated = c.scratch_allocated_bytes.value_or(0);
    s.current_driver_object_bytes = c.driver_object_bytes;
    s.implicit_used_given = c.implicit_used_bytes;
    s.current_query.reset();
    s.current_implicit_used = 0;
}

void Analyzer::on_region(const RegionInfo& region) {
    State& s = *state_;
    s.require_open("on_region");
    const uint64_t cmd = s.current.ordinal;
    if (static_cast<int>(region.role) >= kRegionRoleCount)
        throw AnalysisInputError(
            fmt::format("command {}: region {} has role {}, not a known region role", cmd,
                        region.id, static_cast<int>(region.role)));
    if (region.size > UINT64_MAX - region.base)
        throw AnalysisInputError(
            fmt::format("command {}: region {} '{}' at 0x{:x} + {} bytes passes the end of the "
                        "64-bit address space",
                        cmd, region.id, region.label, region.base, region.size));

    AnalysisReport& r = s.report;
    ++r.region_uses;
    uint64_t newer_first_use = cmd;
    std::optional<uint64_t>
        newer_previous_use;  // the last command before this one that used the region
    auto it = s.regions.find(region.id);
    if (it != s.regions.end()) {
        RegionRow& row = it->second;
        if (row.base != region.base || row.size != region.size || row.role != region.role)
            throw AnalysisInputError(
                fmt::format("command {}: region {} reported as {} 0x{:x}+{} but first seen at "
                            "command {} as {} 0x{:x}+{}: "
                            "a region id names one range and role for the whole trace",
                            cmd, region.id, region_role_name(region.role), region.base, region.size,
                            row.first_command, region_role_name(row.role), row.base, row.size));
        newer_first_use = row.first_command;
        if (row.last_command != cmd) newer_previous_use = row.last_command;
        row.last_command = cmd;
        ++row.uses;
        row.written = row.written || region.written;
    } else if (s.regions.size() < s.limits.max_tracked_regions) {
        RegionRow row{region.id, region.label, region.base, region.size,   region.role,
                      cmd,       cmd,          1,           region.written};
        s.regions.emplace(region.id, std::move(row));
    } else {
        ++r.region_uses_not_tracked;
    }

    if (region.role == RegionRole::kImplicitData && !s.implicit_allocated_given)
        s.current.implicit_allocated += region.size;
    if (region.role == RegionRole::kScratch && !s.scratch_allocated_given)
        s.current.scratch_allocated += region.size;

    if (region.role == RegionRole::kBuffer || region.size == 0) return;
    s.taken.clear();
    s.owners.paint(region.base, region.size,
                   AddressOwner{region.id, region.role, cmd, region.written}, s.taken);
    for (const OwnerOverlap& o : s.taken) {
        if (o.previous.command == cmd && contained_by_design(o.previous.role, region.role))
            continue;
        // Reading bytes another region only read (shared vertices, a CLAS two BLAS reference) is
        // sharing, not reuse: neither use changes what the other sees.
        if (!o.previous.written && !region.written) continue;
        // The same dstImplicitData rebuilt: the objects of its previous build lived inside it.
        if (region.role == RegionRole::kImplicitData && is_object_role(o.previous.role) &&
            (o.previous.command == newer_previous_use || o.previous.command == cmd))
            continue;
        PendingOverlap p;
        p.older = o.previous;
        p.newer_region = region.id;
        p.newer_role = region.role;
        p.base = o.base;
        p.size = o.size;
        p.kind =
            newer_first_use <= o.previous.command ? OverlapKind::kAliasing : OverlapKind::kReuse;
        s.pending_overlaps.push_back(p);
    }
}

void Analyzer::on_object(const ObjectInfo& o) {
    State& s = *state_;
    s.require_open("on_object");
    const uint64_t cmd = s.current.ordinal;
    if (o.truncate_bits > 32)
        throw AnalysisInputError(fmt::format(
            "command {} op {}: positionTruncateBitCount {} exceeds 32 (a float has 32 bits)", cmd,
            o.op_index, o.truncate_bits));
    if (static_cast<int>(o.type) > static_cast<int>(ObjectType::kOther))
        throw AnalysisInputError(fmt::format("command {} op {}: object type {} is not known", cmd,
                                             o.op_index, static_cast<int>(o.type)));
    AnalysisReport& r = s.report;
    ++r.objects;
    OpTypeSizes& t = r.by_op_type[static_cast<int>(s.current.op_type)];
    ++t.objects;
    t.triangles += o.triangles;
    t.vertices += o.vertices;
    t.engine_bytes.add(o.engine_bytes);
    if (o.driver_bytes) {
        t.driver_bytes.add(*o.driver_bytes);
        ++t.objects_with_driver_bytes;
        t.engine_bytes_of_driver_objects += o.engine_bytes;
        s.current.driver_bytes += *o.driver_bytes;
    }
    ++s.current.objects;
    s.current.engine_bytes += o.engine_bytes;
    if (s.current.op_mode == OpMode::kImplicitDestinations)
        s.current_implicit_used += o.engine_bytes;

    if (o.type == ObjectType::kClas || o.type == ObjectType::kClusterTemplate) {
        TruncationRow& tr = s.truncation[o.truncate_bits];
        tr.truncate_bits = o.truncate_bits;
        ++tr.objects;
        tr.triangles += o.triangles;
        tr.engine_bytes += o.engine_bytes;
        if (o.engine_bytes_untruncated) {
            ++tr.objects_with_untruncated;
            tr.engine_bytes_of_those += o.engine_bytes;
            tr.untruncated_bytes += *o.engine_bytes_untruncated;
        }
    }
}

void Analyzer::on_build_sizes(const BuildSizesInfo& sizes) {
    State& s = *state_;
    s.require_open("on_build_sizes");
    s.current_query = sizes;
}

void Analyzer::on_hazard(const HazardSummary& h) {
    State& s = *state_;
    s.require_open("on_hazard");
    if (h.second_command != s.current.ordinal)
        throw AnalysisInputError(
            fmt::format("hazard '{}' names second command {} while command {} is open: report a "
                        "hazard with the command "
                        "that completes it",
                        h.hazard_class, h.second_command, s.current.ordinal));
    if (h.first_command > h.second_command)
        throw AnalysisInputError(
            fmt::format("hazard '{}': first command {} comes after second command {}",
                        h.hazard_class, h.first_command, h.second_command));
    if (h.size > UINT64_MAX - h.base)
        throw AnalysisInputError(
            fmt::format("hazard '{}' at 0x{:x} + {} bytes passes the end of the address space",
                        h.hazard_class, h.base, h.size));
    s.pending_hazards.push_back(h);
}

void Analyzer::on_trace_bytes(const TraceBytes& bytes) { state_->report.trace_bytes = bytes; }

void Analyzer::on_gpu_span(const GpuSpan& span) {
    State& s = *state_;
    if (span.first_ordinal > span.last_ordinal)
        throw AnalysisInputError(
            fmt::format("GPU span: first command {} comes after last command {}",
                        span.first_ordinal, span.last_ordinal));
    AnalysisReport& r = s.report;
    r.gpu_timing_present = true;
    ++r.gpu_spans_total;
    r.gpu_spans_ops += span.ops;
    r.gpu_spans_triangles += span.triangles;
    r.gpu_spans_ns =
        r.gpu_spans_ns > UINT64_MAX - span.gpu_ns ? UINT64_MAX : r.gpu_spans_ns + span.gpu_ns;
    if (r.gpu_spans.size() < s.limits.max_listed_gpu_spans)
        r.gpu_spans.push_back(GpuSpanRow{span, 0, {}});
}

void Analyzer::on_gpu_clock(const GpuClock& clock) {
    if (!(clock.timestamp_period_ns > 0) || !(clock.timestamp_period_ns < 1e12))
        throw AnalysisInputError(
            fmt::format("timestamp period {} ns is not a positive finite period",
                        clock.timestamp_period_ns));
    state_->report.gpu_clock = clock;
}

void Analyzer::on_note(std::string note) {
    auto& notes = state_->report.notes;
    if (notes.size() < 64) notes.push_back(std::move(note));
}

void Analyzer::State::close_command() {
    add_command_sizes();
    const std::vector<uint64_t> hazard_matches = meet_overlaps_with_hazards();
    list_hazards(hazard_matches);
    // A hazard's second command is listed even past the cap, so its link has a target.
    bool force_list = !pending_hazards.empty() && report.hazards_not_listed == 0;
    pending_overlaps.clear();
    pending_hazards.clear();

    add_to_kinds(current);

    if (report.commands_listed.size() < limits.max_listed_commands || force_list)
        report.commands_listed.push_back(current);
    recent.push_back(current);
    if (recent.size() > limits.recent_command_rows) recent.pop_front();
    top_gpu.offer(current, limits.top_commands);
    top_replay.offer(current, limits.top_commands);
    add_to_timeline(current);
    open = false;
}

// Build sizes: worst case (implicit: the whole buffer; explicit: per object) vs actual, and
// scratch, into the command's row and its op type's totals.
void Analyzer::State::add_command_sizes() {
    OpTypeSizes& t = report.by_op_type[static_cast<int>(current.op_type)];
    if (current_query && (current.op_mode == OpMode::kImplicitDestinations ||
                          current.op_mode == OpMode::kExplicitDestinations)) {
        const BuildSizesInfo& q = *current_query;
        uint64_t worst = q.acceleration_structure_size;
        if (current.op_mode == OpMode::kExplicitDestinations) {
            uint64_t n = current.op_count;
            worst = (n != 0 && worst > UINT64_MAX / n) ? UINT64_MAX : worst * n;
        }
        current.worst_case_bytes = worst;
        ++t.commands_with_query;
        t.worst_case_bytes += worst;
        t.actual_bytes_of_queried += current.engine_bytes;
    }
    if (current_query) {
        current.scratch_required = current_query->build_scratch_size;
        t.scratch_required += current_query->build_scratch_size;
    }
    if (current.op_mode == OpMode::kImplicitDestinations) {
        t.implicit_allocated += current.implicit_allocated;
        t.implicit_used += implicit_used_given.value_or(current_implicit_used);
    }
    t.scratch_allocated += current.scratch_allocated;
    if (current.scratch_used) t.scratch_used += *current.scratch_used;
}

// Overlaps found during this command meet the hazards replay reported for it; returns how many
// overlaps each hazard met.
std::vector<uint64_t> Analyzer::State::meet_overlaps_with_hazards() {
    std::vector<uint64_t> hazard_matches(pending_hazards.size(), 0);
    for (const PendingOverlap& p : pending_overlaps) {
        const int matched = hazard_of(p);
        const bool hazard = matched >= 0;
        if (hazard) ++hazard_matches[matched];
        ++report.overlap_events;
        if (hazard) ++report.overlap_hazard_events;
        add_to_summary(p, hazard);
        OverlapRow* row = overlap_row_for(p, hazard);
        if (!row) continue;
        ++row->events;
        if (p.kind == OverlapKind::kAliasing) row->kind = OverlapKind::kAliasing;
        if (hazard && !row->hazard) {
            row->hazard = true;
            row->hazard_class = pending_hazards[matched].hazard_class;
            if (report.hazards.size() + matched < limits.max_listed_hazards)
                row->hazard_index = report.hazards.size() + matched;
        }
    }
    return hazard_matches;
}

// The index of the first pending hazard from the overlap's older command over its bytes, or -1.
int Analyzer::State::hazard_of(const PendingOverlap& p) const {
    for (std::size_t i = 0; i < pending_hazards.size(); ++i) {
        const HazardSummary& h = pending_hazards[i];
        if (h.first_command != p.older.command) continue;
        if (h.size != 0 && !ranges_intersect(h.base, h.size, p.base, p.size)) continue;
        return static_cast<int>(i);
    }
    return -1;
}

void Analyzer::State::add_to_summary(const PendingOverlap& p, bool hazard) {
    SummaryKey key{static_cast<int>(p.older.role), static_cast<int>(p.newer_role),
                   static_cast<int>(p.kind), hazard};
    OverlapSummaryRow& sr = summary[key];
    sr.older_role = p.older.role;
    sr.newer_role = p.newer_role;
    sr.kind = p.kind;
    sr.hazard = hazard;
    ++sr.events;
    sr.bytes += p.size;
}

// The listed row of the overlap's region pair, grown to cover it, or a new row while the
// listing has room; null (counted as not listed) past the cap.
OverlapRow* Analyzer::State::overlap_row_for(const PendingOverlap& p, bool hazard) {
    AnalysisReport& r = report;
    auto pair = std::make_pair(p.older.region, p.newer_region);
    auto found = overlap_index.find(pair);
    if (found != overlap_index.end()) {
        OverlapRow* row = &r.overlaps[found->second];
        uint64_t lo = std::min(row->base, p.base),
                 hi = std::max(row->base + row->size, p.base + p.size);
        row->base = lo;
        row->size = hi - lo;
        return row;
    }
    if (r.overlaps.size() < limits.max_listed_overlaps ||
        (hazard && hazard_pairs_past_cap < limits.max_listed_hazards)) {
        // Hazards are what a reader looks for: their pairs are listed past the cap, up to the
        // hazard listing limit.
        if (r.overlaps.size() >= limits.max_listed_overlaps) ++hazard_pairs_past_cap;
        overlap_index.emplace(pair, r.overlaps.size());
        r.overlaps.push_back(new_overlap_row(p));
        return &r.overlaps.back();
    }
    ++r.overlap_events_not_listed;
    return nullptr;
}

OverlapRow Analyzer::State::new_overlap_row(const PendingOverlap& p) const {
    OverlapRow o;
    o.older_region = p.older.region;
    o.newer_region = p.newer_region;
    o.older_role = p.older.role;
    o.newer_role = p.newer_role;
    o.older_command = p.older.command;
    o.newer_command = current.ordinal;
    o.base = p.base;
    o.size = p.size;
    o.kind = p.kind;
    auto older_it = regions.find(p.older.region);
    if (older_it != regions.end()) o.older_label = older_it->second.label;
    auto newer_it = regions.find(p.newer_region);
    if (newer_it != regions.end()) o.newer_label = newer_it->second.label;
    return o;
}

// Hazards: listed (with their first command's row, if still recent) up to the cap.
void Analyzer::State::list_hazards(const std::vector<uint64_t>& hazard_matches) {
    AnalysisReport& r = report;
    for (std::size_t i = 0; i < pending_hazards.size(); ++i) {
        ++r.hazards_total;
        ++current.hazards;
        if (r.hazards.size() < limits.max_listed_hazards) {
            r.hazards.push_back(HazardRow{r.hazards.size(), pending_hazards[i], hazard_matches[i]});
            const uint64_t first = pending_hazards[i].first_command;
            bool listed = std::any_of(r.commands_listed.begin(), r.commands_listed.end(),
                                      [&](const CommandRow& c) { return c.ordinal == first; });
            if (!listed && first != current.ordinal)
                if (const CommandRow* rc = find_recent(first)) r.commands_listed.push_back(*rc);
        } else {
            ++r.hazards_not_listed;
        }
    }
}

void Analyzer::State::add_to_kinds(const CommandRow& c) {
    constexpr std::size_t kMaxKinds = 64;
    auto it = kind_index.find(c.name);
    if (it == kind_index.end()) {
        if (report.command_kinds.size() >= kMaxKinds) {
            ++report.command_kinds_not_listed;
            return;
        }
        it = kind_index.emplace(c.name, report.command_kinds.size()).first;
        report.command_kinds.push_back(CommandKindRow{});
        report.command_kinds.back().name = c.name;
    }
    CommandKindRow& k = report.command_kinds[it->second];
    ++k.commands;
    k.ops += c.op_count;
    k.triangles += c.triangles;
    k.objects += c.objects;
    k.engine_bytes += c.engine_bytes;
    k.driver_bytes += c.driver_bytes + current_driver_object_bytes;
    if (c.replay_ns) {
        k.replay_ns += *c.replay_ns;
        ++k.replay_commands;
    }
    if (c.gpu_ns) {
        k.gpu_ns += *c.gpu_ns;
        ++k.gpu_commands;
    }
    k.hazards += c.hazards;
}

void Analyzer::State::add_to_timeline(const CommandRow& c) {
    auto& tl = report.timeline;
    const uint64_t seen = report.commands - 1;  // this command's position in the trace
    if (seen / timeline_width >= limits.timeline_buckets) {
        // Halve the resolution: merge bucket pairs, so memory stays at timeline_buckets.
        std::vector<TimelineBucket> merged;
        for (std::size_t i = 0; i < tl.size(); i += 2) {
            TimelineBucket b = tl[i];
            if (i + 1 < tl.size()) {
                const TimelineBucket& n = tl[i + 1];
                b.last_ordinal = n.last_ordinal;
                b.commands += n.commands;
                b.ops += n.ops;
                b.triangles += n.triangles;
                b.replay_ns += n.replay_ns;
                b.gpu_ns += n.gpu_ns;
                b.gpu_commands += n.gpu_commands;
            }
            merged.push_back(b);
        }
        tl.swap(merged);
        timeline_width *= 2;
    }
    const std::size_t bucket = seen / timeline_width;
    if (bucket >= tl.size()) {
        TimelineBucket b;
        b.first_ordinal = c.ordinal;
        tl.push_back(b);
    }
    TimelineBucket& b = tl.back();
    b.last_ordinal = c.ordinal;
    ++b.commands;
    b.ops += c.op_count;
    b.triangles += c.triangles;
    b.replay_ns += c.replay_ns.value_or(0);
    if (c.gpu_ns) {
        b.gpu_ns += *c.gpu_ns;
        ++b.gpu_commands;
    }
}

AnalysisReport Analyzer::finish() {
    State& s = *state_;
    if (s.finished) throw AnalysisInputError("finish() called twice");
    if (s.open) s.close_command();
    s.finished = true;
    AnalysisReport& r = s.report;

    for (const TruncationRow& t : s.truncation)
        if (t.objects > 0) r.truncation.push_back(t);

    std::sort(r.commands_listed.begin(), r.commands_listed.end(),
              [](const CommandRow& a, const CommandRow& b) { return a.ordinal < b.ordinal; });
    r.commands_listed.erase(std::unique(r.commands_listed.begin(), r.commands_listed.end(),
                                        [](const CommandRow& a, const CommandRow& b) {
                                            return a.ordinal == b.ordinal;
                                        }),
                            r.commands_listed.end());
    r.commands_not_listed = r.commands - r.commands_listed.size();

    r.top_by_gpu = s.top_gpu.sorted();
    r.top_by_replay = s.top_replay.sorted();

    // Overlap rows take labels of regions first seen after the overlap was recorded.
    for (OverlapRow& o : r.overlaps) {
        if (auto it = s.regions.find(o.older_region);
            it != s.regions.end() && o.older_label.empty())
            o.older_label = it->second.label;
        if (auto it = s.regions.find(o.newer_region);
            it != s.regions.end() && o.newer_label.empty())
            o.newer_label = it->second.label;
    }
    r.regions = s.regions.size();
    r.region_rows.reserve(s.regions.size());
    for (auto& [id, row] : s.regions) r.region_rows.push_back(std::move(row));
    std::sort(r.region_rows.begin(), r.region_rows.end(),
              [](const RegionRow& a, const RegionRow& b) {
                  return std::tie(a.first_command, a.base, a.id) <
                         std::tie(b.first_command, b.base, b.id);
              });
    for (auto& [key, row] : s.summary) r.overlap_summary.push_back(row);

    // GPU spans on one axis: ns after the first listed span, and on the host clock when the
    // capture calibrated the device clock (ticks before the calibration point count back).
    if (!r.gpu_spans.empty()) {
        const double period = r.gpu_clock ? r.gpu_clock->timestamp_period_ns : 1.0;
        uint64_t first = UINT64_MAX;
        for (const GpuSpanRow& g : r.gpu_spans) first = std::min(first, g.span.start_ticks);
        for (GpuSpanRow& g : r.gpu_spans) {
            g.start_ns = static_cast<uint64_t>(
                static_cast<double>(g.span.start_ticks - first) * period + 0.5);
            if (r.gpu_clock && r.gpu_clock->calibration_ticks && r.gpu_clock->calibration_host_ns) {
                const double delta = (static_cast<double>(g.span.start_ticks) -
                                      static_cast<double>(*r.gpu_clock->calibration_ticks)) *
                                     period;
                const double host = static_cast<double>(*r.gpu_clock->calibration_host_ns) + delta;
                if (host >= 0 && host < 1.8e19) g.host_start_ns = static_cast<uint64_t>(host + 0.5);
            }
        }
    }
    return std::move(r);
}

}  // namespace clastrace::analyze
