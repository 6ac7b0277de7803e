// SPDX-License-Identifier: Apache-2.0
// VK_KHR_acceleration_structure's records: the commands khr_command.cpp runs on the engine,
// and the host records that answer them (the driver's query results, its build sizes).
#include "replayer_internal.h"

namespace clastrace::replay::detail {

bool Replay::on_khr_record(fbs::RecordBody kind, const fbs::Record& r) {
    switch (kind) {
    case fbs::RecordBody::QueryPoolResults:
        khr_.query_results(*r.body_as_QueryPoolResults());
        break;
    // The engine sizes its own shadows; the driver's scratch sizes are what the application's
    // scratch regions are held to (khr_command.cpp).
    case fbs::RecordBody::GetAccelerationStructureBuildSizesKHR:
        khr_.build_sizes(*r.body_as_GetAccelerationStructureBuildSizesKHR());
        break;
    default: return false;
    }
    return true;
}

bool Replay::execute_khr_command(const fbs::Record& record, const CommandRef& ref,
                                 const ReplayLocation& where) {
    switch (record.body_type()) {
    case fbs::RecordBody::CmdBuildAccelerationStructuresKHR:
        khr_.build(*record.body_as_CmdBuildAccelerationStructuresKHR(), ref, where);
        return true;
    case fbs::RecordBody::CmdCopyAccelerationStructure:
        khr_.copy(*record.body_as_CmdCopyAccelerationStructure(), ref, where);
        return true;
    case fbs::RecordBody::CmdCopyAccelerationStructureToMemory:
        khr_.copy_to_memory(*record.body_as_CmdCopyAccelerationStructureToMemory(), ref, where);
        return true;
    case fbs::RecordBody::CmdWriteAccelerationStructuresProperties:
        khr_.write_properties(*record.body_as_CmdWriteAccelerationStructuresProperties(), ref,
                              where);
        return true;
    default: return false;
    }
}

}  // namespace clastrace::replay::detail
