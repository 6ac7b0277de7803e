// SPDX-License-Identifier: Apache-2.0
// CLASTRACE_DEVICE_ADDRESS_WRITES=exact: which bytes a dispatch wrote through buffer device
// addresses. At the pause before a marked dispatch the worker copies every buffer the host can
// see (mapped, or the pause's staged copy) that has a device address; at the pause after, it
// compares and keeps the changed byte ranges with their new bytes. A byte rewritten with the
// value it had is not seen (capture/README.md, "Writes through buffer device addresses").
#pragma once

#include "clastrace/capture/capture_records.h"
#include "clastrace/capture/served_build.h"

#include <cstdint>
#include <map>
#include <span>
#include <tuple>
#include <vector>

namespace clastrace::capture {

// What one execution of a dispatch changed.
struct AddressWriteComparison {
    std::vector<CapturedRange> changed;  // role kShaderWrite, address and buffer/offset set
    uint64_t compared_bytes = 0;
};

class ExactAddressWrites {
public:
    // (submission, pauseId, occurrence): one execution of a dispatch.
    using Key = std::tuple<uint64_t, uint64_t, uint32_t>;
    // At the pause before: copies `buffers` (their host views are valid and invalidated now).
    void before(const Key& key, std::span<const ServedBuffer> buffers);
    // At the pause after: the ranges of `buffers` that differ from the copies `before` took
    // (a buffer created in between, or resized, is not compared). Forgets the copies.
    AddressWriteComparison after(const Key& key, std::span<const ServedBuffer> buffers);

private:
    struct Copy {
        VkDeviceAddress address = 0;
        std::vector<uint8_t> bytes;
    };
    std::map<Key, std::map<uint64_t, Copy>> before_;  // by buffer handle
};

// The changed runs of `now` against `then` (same size), as [begin, end) offsets, exact to the
// byte (no merging across unchanged bytes: those would become false writes).
std::vector<std::pair<uint64_t, uint64_t>> changed_runs(std::span<const uint8_t> then,
                                                        std::span<const uint8_t> now);

}  // namespace clastrace::capture
