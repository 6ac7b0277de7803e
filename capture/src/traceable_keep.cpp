// SPDX-License-Identifier: Apache-2.0
// TraceableEngineBytes (traceable_clusters.h): the engine's bytes of traceable BLASes, laid over
// the driver's BVH wherever a served command reads the application's memory.
#include "traceable_clusters.h"

#include <algorithm>
#include <cstring>

namespace clastrace::capture {

void TraceableEngineBytes::keep(uint64_t address, Entry entry) {
    const uint64_t end = address + entry.driver.size();
    std::lock_guard lock(mutex_);
    auto it = entries_.upper_bound(address);
    if (it != entries_.begin() &&
        std::prev(it)->first + std::prev(it)->second.driver.size() > address)
        --it;
    while (it != entries_.end() && it->first < end) it = entries_.erase(it);
    entries_.emplace(address, std::move(entry));
}

void TraceableEngineBytes::overlay(uint64_t address, uint8_t* bytes, uint64_t size) {
    const uint64_t end = address + size;
    std::lock_guard lock(mutex_);
    auto it = entries_.upper_bound(address);
    if (it != entries_.begin() &&
        std::prev(it)->first + std::prev(it)->second.driver.size() > address)
        --it;
    while (it != entries_.end() && it->first < end) {
        const Entry& e = it->second;
        const uint64_t begin = std::max(it->first, address);
        const uint64_t stop = std::min(it->first + e.driver.size(), end);
        uint8_t* here = bytes + (begin - address);
        const uint64_t from = begin - it->first;
        if (std::memcmp(here, e.driver.data() + from, stop - begin) != 0) {
            it = entries_.erase(it);  // the application wrote there since: its bytes stand
            continue;
        }
        std::memcpy(here, e.engine.data() + from, stop - begin);
        ++it;
    }
}

bool TraceableEngineBytes::find(uint64_t address, Entry& out) const {
    std::lock_guard lock(mutex_);
    auto it = entries_.find(address);
    if (it == entries_.end()) return false;
    out = it->second;
    return true;
}

uint64_t TraceableEngineBytes::driver_size(uint64_t address) const {
    std::lock_guard lock(mutex_);
    auto it = entries_.find(address);
    return it == entries_.end() ? 0 : it->second.driver.size();
}

uint64_t TraceableEngineBytes::kept_bytes() const {
    std::lock_guard lock(mutex_);
    uint64_t total = 0;
    for (const auto& [address, e] : entries_) total += e.engine.size() + e.driver.size();
    return total;
}

}  // namespace clastrace::capture
