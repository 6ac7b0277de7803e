// SPDX-License-Identifier: Apache-2.0
#include <clastrace/traces/records.h>

namespace clastrace::traces {

namespace {
template <class T>
SnapshotLists lists_of(const T* command) {
    if (!command) return {};
    return {command->inputs(), command->outputs()};
}
}  // namespace

SnapshotLists record_snapshots(const fbs::Record& record) {
    using K = fbs::RecordBody;
    switch (record.body_type()) {
    case K::CmdCopyBuffer: return lists_of(record.body_as_CmdCopyBuffer());
    case K::CmdDispatch: return lists_of(record.body_as_CmdDispatch());
    case K::CmdBuildClusterAccelerationStructureIndirect:
        return lists_of(record.body_as_CmdBuildClusterAccelerationStructureIndirect());
    case K::CmdBuildAccelerationStructureNV:
        return lists_of(record.body_as_CmdBuildAccelerationStructureNV());
    case K::CmdCopyMemoryToAccelerationStructure:
        return lists_of(record.body_as_CmdCopyMemoryToAccelerationStructure());
    case K::CmdBuildAccelerationStructuresKHR:
        return lists_of(record.body_as_CmdBuildAccelerationStructuresKHR());
    case K::CmdCopyAccelerationStructure:
        return lists_of(record.body_as_CmdCopyAccelerationStructure());
    case K::CmdCopyAccelerationStructureToMemory:
        return lists_of(record.body_as_CmdCopyAccelerationStructureToMemory());
    case K::CmdTraceRays: {  // inputs only: the indirect parameters as read at execution
        const auto* rays = record.body_as_CmdTraceRays();
        return rays ? SnapshotLists{rays->inputs(), nullptr} : SnapshotLists{};
    }
    case K::MemoryObservation: {
        const auto* o = record.body_as_MemoryObservation();
        return o ? SnapshotLists{o->snapshots(), nullptr} : SnapshotLists{};
    }
    case K::DeviceAddressWrites: {  // the bytes the dispatch wrote: outputs
        const auto* w = record.body_as_DeviceAddressWrites();
        return w ? SnapshotLists{nullptr, w->writes()} : SnapshotLists{};
    }
    default: return {};
    }
}

std::optional<ContentsRecord> contents_record(const fbs::Record& record) {
    if (const auto* c = record.body_as_MemoryContents())
        return ContentsRecord{c->hash(), c->seed(), c->bytes()};
    if (const auto* d = record.body_as_MemoryContentsDelta())
        return ContentsRecord{d->hash(), d->seed(),      d->bytes(),
                              true,      d->base_hash(), d->byte_planes()};
    return std::nullopt;
}

const char* record_kind_name(fbs::RecordBody kind) {
    if (static_cast<unsigned>(kind) >= kRecordKindCount) return "unknown";
    return fbs::EnumNameRecordBody(kind);
}

}  // namespace clastrace::traces
