// SPDX-License-Identifier: Apache-2.0
// Small helpers over the generated record types that every consumer needs.
#pragma once

#include <clastrace/traces/trace_generated.h>

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

// "CmdBuildClusterAccelerationStructureIndirect", or "unknown(<n>)" style names for
// kinds newer than this build (returns "unknown").
const char* record_kind_name(fbs::RecordBody kind);

// Number of record kinds this build knows (RecordBody::MAX).
constexpr unsigned kRecordKindCount = static_cast<unsigned>(fbs::RecordBody::MAX) + 1;

}  // namespace clastrace::traces
