// SPDX-License-Identifier: Apache-2.0
// Small helpers over the generated record types that every consumer needs.
#pragma once

#include <clastrace/traces/trace_generated.h>

#include <cstddef>
#include <cstdint>
#include <optional>

namespace clastrace::traces {

using SnapshotVector = flatbuffers::Vector<const fbs::MemorySnapshot*>;

// The memory snapshots a record refers to: what it read and what it wrote.
// MemoryObservation's snapshots count as inputs, DeviceAddressWrites' writes as outputs;
// CmdTraceRays has inputs only. Either may be null.
struct SnapshotLists {
    const SnapshotVector* inputs = nullptr;
    const SnapshotVector* outputs = nullptr;
};
SnapshotLists record_snapshots(const fbs::Record& record);

// A record that defines contents: MemoryContents, or MemoryContentsDelta (format 1.6). The
// reader hands a delta out decoded: its `bytes` hold the real bytes, as a MemoryContents' do
// (only `delta` and `base_hash` tell how it was stored).
struct ContentsRecord {
    uint64_t hash = 0;
    uint64_t seed = 0;
    const flatbuffers::Vector<uint8_t>* bytes = nullptr;  // may be null (no bytes)
    bool delta = false;
    uint64_t base_hash = 0;   // delta only
    uint8_t byte_planes = 0;  // delta only: how the XOR is laid out in the file (0, 1 or 4)
    const uint8_t* data() const { return bytes ? bytes->data() : nullptr; }
    size_t size() const { return bytes ? bytes->size() : 0; }
};
std::optional<ContentsRecord> contents_record(const fbs::Record& record);

// "CmdBuildClusterAccelerationStructureIndirect", or "unknown(<n>)" style names for
// kinds newer than this build (returns "unknown").
const char* record_kind_name(fbs::RecordBody kind);

// Number of record kinds this build knows (RecordBody::MAX).
constexpr unsigned kRecordKindCount = static_cast<unsigned>(fbs::RecordBody::MAX) + 1;

}  // namespace clastrace::traces
