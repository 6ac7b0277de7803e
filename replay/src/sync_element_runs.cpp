// SPDX-License-Identifier: Apache-2.0
// record_accesses' batching: accesses pinned by overlap, and element runs ("x[i]" for
// consecutive i over adjacent bytes) recorded as one record each.
#include "sync_model_internal.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cstring>

namespace clastrace::replay {

namespace {

// Sorts by begin, stably (equal begins keep the command's order), a digit of the begins at a
// time, over only the bits in which they differ: no comparisons, whose branches on addresses
// in no order were most of the cost of sorting by std::sort. The digits split those bits evenly
// (a command's begins differ in ~20 bits: three 7-bit digits, not three or four bytes): for the
// ~180 accesses of a command, clearing and summing 256 buckets a pass was a fifth of the sort.
void sort_by_begin(std::vector<std::pair<uint64_t, uint32_t>>& items,
                   std::vector<std::pair<uint64_t, uint32_t>>& scratch) {
    const std::size_t n = items.size();
    if (n < 2) return;
    uint64_t any = 0, every = ~uint64_t(0);
    for (const auto& item : items) {
        any |= item.first;
        every &= item.first;
    }
    const uint64_t differing = any ^ every;
    if (differing == 0) return;
    const int low = std::countr_zero(differing);
    const int span = 64 - std::countl_zero(differing) - low;
    constexpr int kMaxDigitBits = 8;
    const int digits = (span + kMaxDigitBits - 1) / kMaxDigitBits;
    const int digit_bits = (span + digits - 1) / digits;
    const uint64_t mask = (uint64_t(1) << digit_bits) - 1;
    scratch.resize(n);
    for (int shift = low; shift < low + span; shift += digit_bits) {
        std::array<uint32_t, (1u << kMaxDigitBits) + 1> at;
        std::fill_n(at.begin(), mask + 2, 0u);
        for (const auto& item : items) ++at[((item.first >> shift) & mask) + 1];
        for (std::size_t d = 1; d <= mask; ++d) at[d] += at[d - 1];
        for (const auto& item : items) scratch[at[(item.first >> shift) & mask]++] = item;
        items.swap(scratch);
    }
}

}  // namespace

// Accesses overlapping another of the command keep their place in the order: pinned
// (batch.pinned, by index). batch.by_begin: the accesses with bytes, sorted by begin.
void SyncModel::State::pin_overlapping(std::span<const Access> accesses) {
    const std::size_t n = accesses.size();
    auto& by_begin = batch.by_begin;
    by_begin.clear();
    for (uint32_t i = 0; i < n; ++i)
        if (!accesses[i].range.empty()) by_begin.push_back({accesses[i].range.begin, i});
    sort_by_begin(by_begin, batch.sort_scratch);
    auto& pinned = batch.pinned;
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
}

// Commands of one kind list their accesses alike ("srcInfosArray[7]", then its
// ".indexBuffer", then its ".vertexBuffer", ...), so the field that followed a field last time
// is a good guess for the next access: a text equal to the guess is its id without a hash or a
// probe of the table, which were most of the cost of batching a command's accesses. Guessing
// by what came before, not by position, survives commands whose ops name more or fewer fields.
void SyncModel::State::intern_fields(std::span<const Access> accesses) {
    const std::size_t n = accesses.size();
    auto& field_of = batch.field_of;
    auto& next = batch.next_field;
    field_of.resize(n);
    uint32_t* follows = &batch.first_field;  // where the guess for access i is kept
    for (std::size_t i = 0; i < n; ++i) {
        const std::string_view text = accesses[i].field;
        const uint32_t guess = *follows;
        uint32_t id;
        if (guess != UINT32_MAX && field_texts[guess].length == text.size() &&
            (text.empty() || std::memcmp(field_arena.data() + field_texts[guess].offset,
                                         text.data(), text.size()) == 0)) {
            id = guess;
        } else {
            id = intern(text);
            *follows = id;
        }
        field_of[i] = id;
        if (next.size() <= id) next.resize(field_names.size(), UINT32_MAX);
        follows = &next[id];
    }
}

// Element runs of the non-pinned accesses (batch.runs, run_of, members), each growing while
// the next element continues it; batch.field_of holds each access's interned field.
void SyncModel::State::form_element_runs(std::span<const Access> accesses) {
    const std::size_t n = accesses.size();
    const auto& pinned = batch.pinned;
    // Each access's field, interned once for the run forming below and its record.
    intern_fields(accesses);
    const auto& field_of = batch.field_of;

    // Element runs, each growing while the next element continues it.
    auto& runs = batch.runs;
    runs.clear();
    auto& run_of = batch.run_of;
    auto& next_member = batch.next_member;
    run_of.assign(n, -1);
    next_member.assign(n, -1);
    // Runs still growing, at most one per kind of element (field shape, stage, access, write),
    // each kind kept beside its slot so the search reads no run and no access.
    struct OpenKind {
        uint32_t prefix, suffix;
        StageMask stage;
        AccessMask access;
        bool is_write;
    };
    std::size_t open[8];
    OpenKind open_kind[8];
    std::size_t open_count = 0;
    for (uint32_t i = 0; i < n; ++i) {
        const Access& a = accesses[i];
        if (pinned[i] || a.range.empty()) continue;
        const FieldShape& shape = field_shapes[field_of[i]];
        if (!shape.indexed) continue;
        const uint32_t prefix = shape.prefix, suffix = shape.suffix;
        const uint64_t index = shape.index;
        const uint64_t bytes = a.range.end - a.range.begin;
        std::size_t* slot = nullptr;
        for (std::size_t k = 0; k < open_count; ++k) {
            const OpenKind& o = open_kind[k];
            if (o.prefix == prefix && o.suffix == suffix && o.stage == a.stage &&
                o.access == a.access && o.is_write == a.is_write) {
                slot = &open[k];
                break;
            }
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
        if (slot) {
            *slot = runs.size() - 1;
        } else if (open_count < std::size(open)) {
            open_kind[open_count] = {prefix, suffix, a.stage, a.access, a.is_write};
            open[open_count++] = runs.size() - 1;
        }
    }
    // Each run's members in one flat list: a finding on element k belongs to its k-th access.
    auto& members = batch.members;
    members.clear();
    for (Run& r : runs) {
        r.members_at = uint32_t(members.size());
        for (int32_t m = int32_t(r.head); m >= 0; m = next_member[std::size_t(m)])
            members.push_back(uint32_t(m));
    }
}

}  // namespace clastrace::replay
