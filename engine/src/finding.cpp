// SPDX-License-Identifier: Apache-2.0
#include "clastrace/engine/finding.h"

namespace clastrace::engine {

bool has_rule(const std::vector<Finding>& findings, const std::string& rule) {
    for (const Finding& f : findings)
        if (f.rule == rule) return true;
    return false;
}

}  // namespace clastrace::engine
