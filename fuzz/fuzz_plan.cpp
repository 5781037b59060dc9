// Sweep plans (plan.cpp): parsed as `markerctl sweep check` and the
// sweep.check command take them, then expanded into steps and dry-run
// against the shipped simulated rig (config/rig-sim.toml) as the runner
// does before a run. ConfigError is the one error parsing may raise; the
// dry run raises none.

#include <cstddef>
#include <string>

#include "fuzz_support.hpp"
#include "markerd/base/config_table.hpp"
#include "markerd/rig/rig_config.hpp"
#include "markerd/sweep/plan.hpp"

namespace {

// Plans up to the parser's limit (a million measurements) are valid, but
// expanding and estimating one takes a second under the sanitizers: the dry
// run is left out above this, the parse is not.
constexpr std::size_t kMaxCheckedSteps = 20000;

std::size_t step_count(const markerd::sweep::SweepPlan& plan) {
  std::size_t steps = 0;
  for (const auto& grid : plan.grids) steps += grid.distances_m.size() * grid.angles_deg.size();
  return steps * static_cast<std::size_t>(plan.repeats);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const markerd::rig::RigConfig rig =
      markerd::rig::load_rig_config(markerd::fuzz::config_dir() / "rig-sim.toml");
  markerd::sweep::SweepPlan plan;
  try {
    plan = markerd::sweep::parse_plan(markerd::fuzz::as_text(data, size), "fuzz-plan.toml");
  } catch (const markerd::ConfigError& e) {
    markerd::fuzz::expected_error(e);
    return 0;
  }
  if (step_count(plan) > kMaxCheckedSteps) return 0;
  const auto steps = markerd::sweep::plan_steps(plan);
  if (steps.size() != step_count(plan))
    markerd::fuzz::finding("plan_steps disagrees with the plan's grids and repeats");
  const markerd::sweep::PlanCheck check = markerd::sweep::check_plan(plan, rig, 30.0);
  (void)markerd::sweep::format_plan_check(plan, check);
  return 0;
}
