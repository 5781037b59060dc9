// The GPIO line backends: the recording backend the stepper tests run on, and
// the libgpiod 1.6 backend's errors on a machine without GPIO chips (the HIL
// harness tests it against the kernel's gpio-sim).

#include <gtest/gtest.h>
#include <poll.h>

#include <string>
#include <vector>

#include "markerd/rig/drive.hpp"
#include "markerd/rig/gpio_lines.hpp"
#include "markerd/rig/testing/gpio_recording.hpp"

namespace {

using namespace markerd::rig;

bool readable(int fd) {
  pollfd p{fd, POLLIN, 0};
  return poll(&p, 1, 0) == 1 && (p.revents & POLLIN) != 0;
}

std::string error_of(const auto& action) {
  try {
    action();
  } catch (const DriveError& e) {
    return e.what();
  }
  return "(no DriveError)";
}

TEST(RecordingGpio, RecordsEveryOutputEdgeWithItsLevel) {
  RecordingGpioBackend gpio("gpiochip9", {"STEP", "EN"});
  auto step = gpio.request_output({"gpiochip9", "STEP"}, false, "test");
  auto enable = gpio.request_output({"/dev/gpiochip9", "1", true}, false, "test");  // by path and offset
  EXPECT_TRUE(gpio.level("EN")) << "inactive on an active-low line is high";
  step->set(true);
  step->set(true);  // no change, no edge
  step->set(false);
  enable->set(true);
  const auto steps = gpio.edges("STEP");
  ASSERT_EQ(steps.size(), 2U);
  EXPECT_TRUE(steps[0].active);
  EXPECT_TRUE(steps[0].high);
  EXPECT_FALSE(steps[1].active);
  EXPECT_LE(steps[0].time, steps[1].time);
  const auto enables = gpio.edges("EN");
  ASSERT_EQ(enables.size(), 1U);
  EXPECT_TRUE(enables[0].active);
  EXPECT_FALSE(enables[0].high);
  EXPECT_EQ(gpio.dropped_edges("STEP"), 0U);
}

TEST(RecordingGpio, CountsEdgesBeyondItsBuffer) {
  RecordingGpioBackend gpio("chip", {"STEP"}, 4);
  auto step = gpio.request_output({"chip", "STEP"}, false, "test");
  for (int i = 0; i < 5; ++i) {
    step->set(true);
    step->set(false);
  }
  EXPECT_EQ(gpio.edges("STEP").size(), 4U);
  EXPECT_EQ(gpio.dropped_edges("STEP"), 6U);
}

TEST(RecordingGpio, InputEdgesPollThroughTheEventFd) {
  RecordingGpioBackend gpio("chip", {"LIMIT"});
  gpio.set_level("LIMIT", true);  // a normally closed switch, released
  auto limit = gpio.request_input({"chip", "LIMIT", true}, true, "test");
  EXPECT_FALSE(limit->get());
  ASSERT_GE(limit->event_fd(), 0);
  EXPECT_FALSE(readable(limit->event_fd()));
  gpio.set_level("LIMIT", false);  // the switch opens: active
  gpio.set_level("LIMIT", false);  // no change, no event
  EXPECT_TRUE(limit->get());
  ASSERT_TRUE(readable(limit->event_fd()));
  gpio.set_level("LIMIT", true);
  auto first = limit->read_event();
  ASSERT_TRUE(first);
  EXPECT_TRUE(first->active);
  EXPECT_TRUE(readable(limit->event_fd())) << "one event still queued";
  auto second = limit->read_event();
  ASSERT_TRUE(second);
  EXPECT_FALSE(second->active);
  EXPECT_LE(first->timestamp, second->timestamp);
  EXPECT_FALSE(limit->read_event());
  EXPECT_FALSE(readable(limit->event_fd()));
}

TEST(RecordingGpio, InputsWithoutEventsHaveNoFd) {
  RecordingGpioBackend gpio("chip", {"IN"});
  auto in = gpio.request_input({"chip", "IN"}, false, "test");
  EXPECT_EQ(in->event_fd(), -1);
  gpio.set_level("IN", true);
  EXPECT_TRUE(in->get());
  EXPECT_FALSE(in->read_event());
}

TEST(RecordingGpio, OneConsumerPerLineLikeTheKernel) {
  RecordingGpioBackend gpio("chip", {"STEP", "DIR"});
  {
    auto step = gpio.request_output({"chip", "STEP"}, false, "markerd-rail");
    EXPECT_EQ(gpio.consumer("STEP"), "markerd-rail");
    const auto error = error_of([&] { (void)gpio.request_input({"chip", "0"}, true, "other"); });
    EXPECT_NE(error.find("busy, held by consumer 'markerd-rail'"), std::string::npos) << error;
    EXPECT_NE(error.find("line 0 (STEP)"), std::string::npos) << error;
  }
  EXPECT_FALSE(gpio.consumer("STEP")) << "released with its object";
  EXPECT_NO_THROW((void)gpio.request_output({"chip", "STEP"}, false, "other"));
}

TEST(RecordingGpio, MissingChipsAndLinesAreNamed) {
  RecordingGpioBackend gpio("chip", {"STEP"});
  auto error = error_of([&] { (void)gpio.request_output({"other", "STEP"}, false, "t"); });
  EXPECT_NE(error.find("GPIO chip 'other' not found"), std::string::npos) << error;
  error = error_of([&] { (void)gpio.request_output({"chip", "STPE"}, false, "t"); });
  EXPECT_NE(error.find("no line named 'STPE'"), std::string::npos) << error;
  error = error_of([&] { (void)gpio.request_output({"chip", "3"}, false, "t"); });
  EXPECT_NE(error.find("line offset 3 out of range: the chip has 1 lines"), std::string::npos) << error;
}

// This machine has no /dev/gpiochip*: the errors must say so, and name what
// was asked for. (With chips present, they list them instead.)
TEST(Gpiod1Backend, MissingChipByPathNameAndLabel) {
  auto gpio = make_gpiod1_backend();
  auto error = error_of([&] { (void)gpio->request_output({"/dev/gpiochip977", "17"}, false, "test"); });
  EXPECT_NE(error.find("GPIO chip '/dev/gpiochip977' (/dev/gpiochip977): No such file or directory"), std::string::npos)
      << error;
  EXPECT_TRUE(error.find("no GPIO chips") != std::string::npos ||
              error.find("chips on this system:") != std::string::npos)
      << error;
  error = error_of([&] { (void)gpio->request_input({"gpiochip977", "LIMIT"}, true, "test"); });
  EXPECT_NE(error.find("GPIO chip 'gpiochip977' (/dev/gpiochip977)"), std::string::npos) << error;
  error = error_of([&] { (void)gpio->request_input({"no-such-pinctrl", "LIMIT"}, true, "test"); });
  EXPECT_NE(error.find("GPIO chip labelled 'no-such-pinctrl' not found"), std::string::npos) << error;
}

}  // namespace
