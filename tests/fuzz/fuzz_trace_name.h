// SPDX-License-Identifier: Apache-2.0
// The file name the fuzz targets give their bytes: not UTF-8, as a Latin-1 file system's
// names are, so every report and JSON document that names the trace meets such bytes.
#pragma once

inline constexpr const char* kFuzzTraceName = "fuzz-caf\xe9.clt";
