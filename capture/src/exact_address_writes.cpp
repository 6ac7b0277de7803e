// SPDX-License-Identifier: Apache-2.0
#include "clastrace/capture/exact_address_writes.h"

#include "clastrace/capture/uncached_copy.h"

#include <algorithm>
#include <cstring>

namespace clastrace::capture {

namespace {

std::vector<uint8_t> host_copy(const ServedBuffer& b) {
    std::vector<uint8_t> bytes(b.size);
    if (b.size == 0) return bytes;
    if (b.cached)
        std::memcpy(bytes.data(), b.host, b.size);
    else
        copy_from_uncached(bytes.data(), b.host, b.size);
    return bytes;
}

}  // namespace

std::vector<std::pair<uint64_t, uint64_t>> changed_runs(std::span<const uint8_t> then,
                                                        std::span<const uint8_t> now) {
    std::vector<std::pair<uint64_t, uint64_t>> runs;
    const uint64_t size = std::min(then.size(), now.size());
    uint64_t i = 0;
    while (i < size) {
        // Whole equal words are skipped eight bytes at a time; most memory is unchanged.
        if (i + 8 <= size && std::memcmp(then.data() + i, now.data() + i, 8) == 0) {
            i += 8;
            continue;
        }
        if (then[i] == now[i]) {
            ++i;
            continue;
        }
        const uint64_t begin = i;
        while (i < size && then[i] != now[i]) ++i;
        runs.emplace_back(begin, i);
    }
    return runs;
}

void ExactAddressWrites::before(const Key& key, std::span<const ServedBuffer> buffers) {
    auto& copies = before_[key];
    copies.clear();
    for (const ServedBuffer& b : buffers)
        if (b.host && b.address) copies[b.buffer] = Copy{b.address, host_copy(b)};
}

AddressWriteComparison ExactAddressWrites::after(const Key& key,
                                                 std::span<const ServedBuffer> buffers) {
    AddressWriteComparison result;
    auto found = before_.find(key);
    if (found == before_.end()) return result;
    const std::map<uint64_t, Copy> copies = std::move(found->second);
    before_.erase(found);
    for (const ServedBuffer& b : buffers) {
        auto copy = copies.find(b.buffer);
        if (!b.host || copy == copies.end() || copy->second.bytes.size() != b.size ||
            copy->second.address != b.address)
            continue;
        const std::vector<uint8_t> now = host_copy(b);
        result.compared_bytes += b.size;
        for (const auto& [begin, end] : changed_runs(copy->second.bytes, now)) {
            CapturedRange r;
            r.role = MemoryRole::kShaderWrite;
            r.address = b.address + begin;
            r.buffer = b.buffer;
            r.buffer_offset = begin;
            std::memcpy(r.bytes.fill(end - begin), now.data() + begin, end - begin);
            result.changed.push_back(std::move(r));
        }
    }
    return result;
}

}  // namespace clastrace::capture
