// SPDX-License-Identifier: Apache-2.0
// SyncModel's bookkeeping: queue slots and interned field names.
#include "sync_model_internal.h"

#include <cstring>

namespace clastrace::replay {

namespace {

// "srcInfosArray[12].vertexBuffer" -> "srcInfosArray[", 12, "].vertexBuffer". Only the
// canonical spelling of the index (no leading zeros) counts, so the text rebuilt from the
// parts is the field itself.
bool split_indexed_field(std::string_view field, std::string_view* prefix, uint64_t* index,
                         std::string_view* suffix) {
    const std::size_t open = field.find('[');
    if (open == std::string_view::npos) return false;
    std::size_t i = open + 1;
    uint64_t value = 0;
    while (i < field.size() && field[i] >= '0' && field[i] <= '9' && i - open <= 9)
        value = value * 10 + uint64_t(field[i++] - '0');
    const std::size_t digits = i - open - 1;
    if (digits == 0 || i >= field.size() || field[i] != ']' ||
        (digits > 1 && field[open + 1] == '0'))
        return false;
    *prefix = field.substr(0, open + 1);
    *index = value;
    *suffix = field.substr(i);
    return true;
}

}  // namespace

uint16_t SyncModel::State::queue_slot(QueueId id) {
    for (std::size_t i = 0; i < queues.size(); ++i)
        if (queues[i].id == id) return uint16_t(i);
    Queue q;
    q.id = id;
    queues.push_back(std::move(q));
    for (Queue& each : queues) each.known.resize(queues.size(), 0);
    for (auto& [handle, fence] : fences) fence.clock.resize(queues.size(), 0);
    for (auto& [handle, sem] : semaphores) {
        if (sem.binary_signal) sem.binary_signal->resize(queues.size(), 0);
        for (auto& [value, clock] : sem.timeline) clock.resize(queues.size(), 0);
    }
    return uint16_t(queues.size() - 1);
}

uint64_t SyncModel::State::field_hash(std::string_view v) {
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

uint32_t SyncModel::State::intern(std::string_view field) {
    const uint64_t h = field_hash(field);
    const std::size_t mask = field_table.size() - 1;
    for (std::size_t i = h & mask;; i = (i + 1) & mask) {
        const FieldSlot& slot = field_table[i];
        if (slot.id == UINT32_MAX) break;
        if (slot.hash == h && slot.length == field.size() &&
            (field.empty() ||
             std::memcmp(field_arena.data() + slot.offset, field.data(), field.size()) == 0))
            return slot.id;
    }
    const uint32_t id = uint32_t(field_names.size());
    field_names.emplace_back(field);
    field_shapes.emplace_back();
    const std::size_t offset = field_arena.size();
    field_arena.append(field);
    field_texts.push_back({offset, field.size()});
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

void SyncModel::State::place_field(FieldSlot slot) {
    const std::size_t mask = field_table.size() - 1;
    std::size_t i = slot.hash & mask;
    while (field_table[i].id != UINT32_MAX) i = (i + 1) & mask;
    field_table[i] = slot;
}

}  // namespace clastrace::replay
