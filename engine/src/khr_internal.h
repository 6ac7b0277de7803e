// SPDX-License-Identifier: Apache-2.0
// Pieces of vkCmdBuildAccelerationStructuresKHR that khr_build.cpp and khr_checks.cpp share.
#pragma once

#include "clastrace/engine/khr_build.h"
#include "nv_gather.h"

#include <string>

namespace clastrace::engine::khr {

// "pInfos[i]."
std::string info_prefix(size_t info);
// Primitive (or instance) counts of the info's ranges, one per geometry.
std::vector<uint32_t> primitive_counts(const KhrBuildInfo& info);
bool ranges_overlap(uint64_t a, uint64_t an, uint64_t b, uint64_t bn);

// One info's checks that only its parameters and memory decide; `c` carries the NV form of
// the info. Claims the scratch range. False when the info cannot run.
bool check_info(nv::Context& c, const KhrBuildInfo& info, const KhrLimits& limits);
// Rules between the elements of pInfos, before any runs (dst, src and scratch aliasing).
void check_between_infos(const KhrBuildCommand& command, ExecutionRecord& record);
// After all ran: a dst that another info's instances read (None-03407, 03706).
void check_instances_against_dsts(const KhrBuildCommand& command, ExecutionRecord& record);

}  // namespace clastrace::engine::khr
