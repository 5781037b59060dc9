#include "markerd/daemon/control/sweep_commands.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

namespace markerd::daemon {

namespace {

using nlohmann::json;

sweep::SweepPlan plan_argument(const json& request) {
  const auto text = string_argument(request, "plan");
  if (!text) throw ControlError("argument 'plan' is missing: the plan's TOML text (markerctl sweep reads the file)");
  const std::string source = string_argument(request, "source").value_or("<plan>");
  try {
    return sweep::parse_plan(*text, source);  // refuses a text over sweep::kMaxPlanBytes, saying so
  } catch (const ConfigError& e) {
    throw ControlError(e.what());
  }
}

json check_json(const sweep::PlanCheck& check, const sweep::SweepPlan& plan) {
  json steps = json::array();
  for (const sweep::PlanStep& s : check.steps) {
    if (s.repeat != 0) continue;  // one line per point
    steps.push_back({{"point", s.point},
                     {"grid", plan.grids[s.grid].name},
                     {"distance_m", s.distance_m},
                     {"angle_deg", s.angle_deg}});
  }
  return {{"plan", plan.name},
          {"points", check.points},
          {"steps", check.steps.size()},
          {"frames_per_point", plan.frames_per_point},
          {"repeats", plan.repeats},
          {"estimated_s", check.estimated_duration.count()},
          {"problems", check.problems},
          {"fits", check.ok()},
          {"warnings", check.warnings},
          {"text", sweep::format_plan_check(plan, check)},
          {"point_list", std::move(steps)}};
}

}  // namespace

void register_sweep_commands(ControlServer& server, sweep::SweepRunner& runner) {
  server.register_command(
      "sweep.check",
      [&runner](const json& request) {
        expect_arguments(request, {"plan", "source"});
        const sweep::SweepPlan plan = plan_argument(request);
        try {
          return check_json(runner.check(plan), plan);
        } catch (const sweep::SweepError& e) {
          throw ControlError(e.what());
        }
      },
      "the dry run of a plan (plan: its TOML text): its points, what does not fit the rig, the estimated duration");
  server.register_command(
      "sweep.start",
      [&runner](const json& request) {
        expect_arguments(request, {"plan", "source"});
        try {
          const auto directory = runner.start(plan_argument(request));
          const sweep::SweepProgress p = runner.progress();
          spdlog::info("control: sweep.start: {}", p.run_id);
          return json{{"run_id", p.run_id}, {"run_directory", directory.string()}, {"steps", p.steps_total}};
        } catch (const sweep::SweepError& e) {
          throw ControlError(e.what());
        }
      },
      "start a run of a plan (plan: its TOML text); one run at a time");
  server.register_command(
      "sweep.status",
      [&runner](const json& request) {
        expect_arguments(request, {});
        return to_json(runner.progress());
      },
      "the run's state, step, progress, last detection rate and estimated time to finish");
  const auto simple = [&server, &runner](const char* name, void (sweep::SweepRunner::*action)(), const char* help) {
    server.register_command(
        name,
        [&runner, action, name](const json& request) {
          expect_arguments(request, {});
          try {
            (runner.*action)();
          } catch (const sweep::SweepError& e) {
            throw ControlError(e.what());
          }
          spdlog::info("control: {}", name);
          return json(nullptr);
        },
        help);
  };
  simple("sweep.pause", &sweep::SweepRunner::pause, "pause the run after stopping the axes where they are");
  simple("sweep.resume", &sweep::SweepRunner::resume, "resume a paused run at the step it paused in");
  server.register_command(
      "sweep.abort",
      [&runner](const json& request) {
        expect_arguments(request, {"reason"});
        try {
          runner.abort(string_argument(request, "reason").value_or("aborted by the operator"));
        } catch (const sweep::SweepError& e) {
          throw ControlError(e.what());
        }
        spdlog::info("control: sweep.abort");
        return json(nullptr);
      },
      "end the run: the axes stop and are disabled, the records say why (reason: text)");
}

}  // namespace markerd::daemon
