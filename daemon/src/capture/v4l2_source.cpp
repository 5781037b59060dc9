#include "markerd/daemon/capture/v4l2_source.hpp"

#include <fcntl.h>
#include <linux/videodev2.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <map>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <system_error>
#include <utility>

#include "markerd/base/errno_text.hpp"
#include "markerd/base/unique_fd.hpp"
#include "markerd/daemon/capture/pixel_convert.hpp"
#include "markerd/base/config_table.hpp"

namespace markerd::daemon {

namespace fs = std::filesystem;
using Kind = CaptureError::Kind;

std::string_view to_string(V4l2PixelFormat format) {
  switch (format) {
    case V4l2PixelFormat::grey: return "GREY";
    case V4l2PixelFormat::yuyv: return "YUYV";
    case V4l2PixelFormat::nv12: return "NV12";
    case V4l2PixelFormat::mjpg: return "MJPG";
  }
  return "?";
}

std::uint32_t fourcc_of(V4l2PixelFormat format) {
  switch (format) {
    case V4l2PixelFormat::grey: return V4L2_PIX_FMT_GREY;
    case V4l2PixelFormat::yuyv: return V4L2_PIX_FMT_YUYV;
    case V4l2PixelFormat::nv12: return V4L2_PIX_FMT_NV12;
    case V4l2PixelFormat::mjpg: return V4L2_PIX_FMT_MJPEG;
  }
  return 0;
}

std::string fourcc_text(std::uint32_t fourcc) {
  std::string text;
  for (int i = 0; i < 4; ++i) {
    const auto c = static_cast<char>((fourcc >> (8 * i)) & 0x7f);
    text += std::isprint(static_cast<unsigned char>(c)) != 0 ? c : '.';
  }
  while (!text.empty() && text.back() == ' ') text.pop_back();
  if ((fourcc & (1U << 31)) != 0) text += "-BE";
  return text;
}

std::string v4l2_control_name(std::string_view label) {
  std::string name;
  bool separate = false;
  for (const char c : label) {
    if (std::isalnum(static_cast<unsigned char>(c)) != 0) {
      if (separate) name += '_';
      separate = false;
      name += static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    } else if (!name.empty()) {
      separate = true;
    }
  }
  return name;
}

namespace {

int xioctl(int fd, unsigned long request, void* arg) noexcept {
  int result = 0;
  do {
    result = ::ioctl(fd, request, arg);
  } while (result == -1 && errno == EINTR);
  return result;
}

template <std::size_t N>
std::string c_text(const std::uint8_t (&chars)[N]) {
  const auto* begin = reinterpret_cast<const char*>(chars);
  return {begin, strnlen(begin, N)};
}
template <std::size_t N>
std::string c_text(const char (&chars)[N]) {
  return {chars, strnlen(chars, N)};
}

std::string lower(std::string_view text) {
  std::string out(text);
  std::transform(out.begin(), out.end(), out.begin(), [](unsigned char c) { return std::tolower(c); });
  return out;
}

// ---------------------------------------------------------------- device queries

std::uint32_t device_caps(const v4l2_capability& cap) {
  return (cap.capabilities & V4L2_CAP_DEVICE_CAPS) != 0 ? cap.device_caps : cap.capabilities;
}

V4l2Intervals enum_intervals(int fd, std::uint32_t fourcc, std::uint32_t width, std::uint32_t height) {
  V4l2Intervals intervals;
  for (std::uint32_t i = 0; i < 256; ++i) {
    v4l2_frmivalenum e{};
    e.index = i;
    e.pixel_format = fourcc;
    e.width = width;
    e.height = height;
    if (xioctl(fd, VIDIOC_ENUM_FRAMEINTERVALS, &e) != 0) break;
    if (e.type == V4L2_FRMIVAL_TYPE_DISCRETE) {
      intervals.discrete.push_back({e.discrete.numerator, e.discrete.denominator});
    } else {
      intervals.min = V4l2Fraction{e.stepwise.min.numerator, e.stepwise.min.denominator};
      intervals.max = V4l2Fraction{e.stepwise.max.numerator, e.stepwise.max.denominator};
      intervals.step = V4l2Fraction{e.stepwise.step.numerator, e.stepwise.step.denominator};
      break;
    }
  }
  return intervals;
}

std::vector<V4l2FormatInfo> enum_formats(int fd, std::uint32_t buffer_type) {
  std::vector<V4l2FormatInfo> formats;
  for (std::uint32_t i = 0; i < 256; ++i) {
    v4l2_fmtdesc desc{};
    desc.index = i;
    desc.type = buffer_type;
    if (xioctl(fd, VIDIOC_ENUM_FMT, &desc) != 0) break;
    V4l2FormatInfo format;
    format.fourcc = desc.pixelformat;
    format.fourcc_text = fourcc_text(desc.pixelformat);
    format.description = c_text(desc.description);
    format.compressed = (desc.flags & V4L2_FMT_FLAG_COMPRESSED) != 0;
    format.emulated = (desc.flags & V4L2_FMT_FLAG_EMULATED) != 0;
    for (std::uint32_t j = 0; j < 256; ++j) {
      v4l2_frmsizeenum size{};
      size.index = j;
      size.pixel_format = desc.pixelformat;
      if (xioctl(fd, VIDIOC_ENUM_FRAMESIZES, &size) != 0) break;
      if (size.type == V4L2_FRMSIZE_TYPE_DISCRETE) {
        format.sizes.push_back({size.discrete.width, size.discrete.height,
                                enum_intervals(fd, desc.pixelformat, size.discrete.width, size.discrete.height)});
      } else {
        const auto& s = size.stepwise;
        format.size_range =
            V4l2SizeRange{s.min_width, s.max_width, s.step_width, s.min_height, s.max_height, s.step_height};
        break;
      }
    }
    formats.push_back(std::move(format));
  }
  return formats;
}

std::vector<V4l2InputInfo> enum_inputs(int fd) {
  std::vector<V4l2InputInfo> inputs;
  for (std::uint32_t i = 0; i < 64; ++i) {
    v4l2_input input{};
    input.index = i;
    if (xioctl(fd, VIDIOC_ENUMINPUT, &input) != 0) break;
    const char* type = input.type == V4L2_INPUT_TYPE_TUNER   ? "tuner"
                       : input.type == V4L2_INPUT_TYPE_TOUCH ? "touch"
                                                             : "camera";
    inputs.push_back({input.index, c_text(input.name), type});
  }
  return inputs;
}

const char* control_type_name(std::uint32_t type) {
  switch (type) {
    case V4L2_CTRL_TYPE_INTEGER: return "int";
    case V4L2_CTRL_TYPE_BOOLEAN: return "bool";
    case V4L2_CTRL_TYPE_MENU: return "menu";
    case V4L2_CTRL_TYPE_INTEGER_MENU: return "intmenu";
    case V4L2_CTRL_TYPE_BUTTON: return "button";
    case V4L2_CTRL_TYPE_INTEGER64: return "int64";
    case V4L2_CTRL_TYPE_BITMASK: return "bitmask";
    case V4L2_CTRL_TYPE_STRING: return "string";
    default: return "compound";
  }
}

bool has_numeric_value(std::uint32_t type) {
  switch (type) {
    case V4L2_CTRL_TYPE_INTEGER:
    case V4L2_CTRL_TYPE_BOOLEAN:
    case V4L2_CTRL_TYPE_MENU:
    case V4L2_CTRL_TYPE_INTEGER_MENU:
    case V4L2_CTRL_TYPE_INTEGER64:
    case V4L2_CTRL_TYPE_BITMASK: return true;
    default: return false;
  }
}

std::vector<std::string> control_flag_names(std::uint32_t flags) {
  std::vector<std::string> names;
  const std::pair<std::uint32_t, const char*> known[] = {{V4L2_CTRL_FLAG_READ_ONLY, "read-only"},
                                                         {V4L2_CTRL_FLAG_INACTIVE, "inactive"},
                                                         {V4L2_CTRL_FLAG_WRITE_ONLY, "write-only"},
                                                         {V4L2_CTRL_FLAG_VOLATILE, "volatile"},
                                                         {V4L2_CTRL_FLAG_GRABBED, "grabbed"}};
  for (const auto& [flag, name] : known) {
    if ((flags & flag) != 0) names.emplace_back(name);
  }
  return names;
}

// One control's description; false when the driver knows no control past `id`.
bool query_control(int fd, std::uint32_t id, bool extended, v4l2_query_ext_ctrl& out) {
  out = {};
  out.id = id;
  if (extended) return xioctl(fd, VIDIOC_QUERY_EXT_CTRL, &out) == 0;
  // Drivers without the control framework know only the old query.
  v4l2_queryctrl old{};
  old.id = id;
  if (xioctl(fd, VIDIOC_QUERYCTRL, &old) != 0) return false;
  out.id = old.id;
  out.type = old.type;
  std::memcpy(out.name, old.name, std::min(sizeof out.name, sizeof old.name));
  out.minimum = old.minimum;
  out.maximum = old.maximum;
  out.step = static_cast<std::uint64_t>(old.step);
  out.default_value = old.default_value;
  out.flags = old.flags;
  return true;
}

std::optional<std::int64_t> read_control(int fd, std::uint32_t id, std::uint32_t type) {
  v4l2_ext_control control{};
  control.id = id;
  v4l2_ext_controls controls{};
  controls.which = V4L2_CTRL_WHICH_CUR_VAL;
  controls.count = 1;
  controls.controls = &control;
  if (xioctl(fd, VIDIOC_G_EXT_CTRLS, &controls) == 0) {
    // Copies: the fields are packed, and optional's constructor takes a reference.
    if (type == V4L2_CTRL_TYPE_INTEGER64) return std::int64_t{control.value64};
    // A bitmask is 32 bits unsigned in the same field.
    if (type == V4L2_CTRL_TYPE_BITMASK) return std::int64_t{static_cast<std::uint32_t>(control.value)};
    return std::int64_t{control.value};
  }
  if (errno != ENOTTY || type == V4L2_CTRL_TYPE_INTEGER64) return std::nullopt;
  v4l2_control old{id, 0};
  if (xioctl(fd, VIDIOC_G_CTRL, &old) != 0) return std::nullopt;
  if (type == V4L2_CTRL_TYPE_BITMASK) return std::int64_t{static_cast<std::uint32_t>(old.value)};
  return std::int64_t{old.value};
}

std::vector<V4l2ControlInfo> enum_controls(int fd) {
  std::vector<V4l2ControlInfo> controls;
  constexpr std::uint32_t next = V4L2_CTRL_FLAG_NEXT_CTRL | V4L2_CTRL_FLAG_NEXT_COMPOUND;
  v4l2_query_ext_ctrl probe{};
  probe.id = next;
  bool extended = xioctl(fd, VIDIOC_QUERY_EXT_CTRL, &probe) == 0 || errno != ENOTTY;
  std::uint32_t id = extended ? next : V4L2_CTRL_FLAG_NEXT_CTRL;
  v4l2_query_ext_ctrl q{};
  for (int guard = 0; guard < 4096 && query_control(fd, id, extended, q); ++guard) {
    id = q.id | (extended ? next : V4L2_CTRL_FLAG_NEXT_CTRL);
    if (q.type == V4L2_CTRL_TYPE_CTRL_CLASS || (q.flags & V4L2_CTRL_FLAG_DISABLED) != 0) continue;
    V4l2ControlInfo c;
    c.id = q.id;
    c.label = c_text(q.name);
    c.name = v4l2_control_name(c.label);
    c.type = control_type_name(q.type);
    c.minimum = q.minimum;
    c.maximum = q.maximum;
    c.step = q.step;
    c.default_value = q.default_value;
    c.flags = control_flag_names(q.flags);
    if (has_numeric_value(q.type) && (q.flags & V4L2_CTRL_FLAG_WRITE_ONLY) == 0 && q.nr_of_dims == 0) {
      c.value = read_control(fd, q.id, q.type);
    }
    if (q.type == V4L2_CTRL_TYPE_MENU || q.type == V4L2_CTRL_TYPE_INTEGER_MENU) {
      for (std::int64_t i = std::max<std::int64_t>(q.minimum, 0); i <= q.maximum && i < 1024; ++i) {
        v4l2_querymenu item{};
        item.id = q.id;
        item.index = static_cast<std::uint32_t>(i);
        if (xioctl(fd, VIDIOC_QUERYMENU, &item) != 0) continue;  // a gap in the menu
        c.menu.push_back({i, q.type == V4L2_CTRL_TYPE_MENU ? c_text(item.name) : std::to_string(item.value)});
      }
    }
    controls.push_back(std::move(c));
  }
  return controls;
}

// "YUYV 640x480 320x240, GREY 16x16 to 4096x2160": what S_FMT can choose from.
std::string offered_formats(int fd) {
  std::string text;
  for (const auto& format : enum_formats(fd, V4L2_BUF_TYPE_VIDEO_CAPTURE)) {
    if (!text.empty()) text += ", ";
    text += format.fourcc_text;
    for (const auto& size : format.sizes) text += fmt::format(" {}x{}", size.width, size.height);
    if (format.size_range) {
      const auto& r = *format.size_range;
      text += fmt::format(" {}x{} to {}x{}", r.min_width, r.min_height, r.max_width, r.max_height);
    }
  }
  return text.empty() ? std::string("nothing it lists") : text;
}

std::string input_list(int fd) {
  std::string text;
  for (const auto& input : enum_inputs(fd)) {
    text += fmt::format("{}{} \"{}\"", text.empty() ? "" : ", ", input.index, input.name);
  }
  return text.empty() ? std::string("none it lists") : text;
}

// ---------------------------------------------------------------- the stream

struct MappedBuffer {
  std::uint8_t* data = nullptr;
  std::size_t length = 0;
};

// One open of the device: its descriptor and mmap buffers. The source holds
// a reference while open, and every frame that borrows one of the buffers
// holds one more; the last to let go unmaps the buffers and closes the
// descriptor. So lent pixels stay valid after close(), and a late release
// hook never reaches a descriptor number that has since been reused for
// another file: the descriptor it uses is still this stream's own.
class Stream {
 public:
  explicit Stream(UniqueFd fd) : fd_(std::move(fd)) {}
  Stream(const Stream&) = delete;
  Stream& operator=(const Stream&) = delete;

  [[nodiscard]] int fd() const noexcept { return fd_.get(); }

  void retain() noexcept { references_.fetch_add(1, std::memory_order_relaxed); }
  void release() noexcept {
    if (references_.fetch_sub(1, std::memory_order_acq_rel) == 1) delete this;
  }

  // Gives a buffer back to the driver; 0 or the errno.
  int queue(std::uint32_t index) noexcept {
    v4l2_buffer buffer{};
    buffer.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buffer.memory = V4L2_MEMORY_MMAP;
    buffer.index = index;
    return xioctl(fd_.get(), VIDIOC_QBUF, &buffer) == 0 ? 0 : errno;
  }

  std::vector<MappedBuffer> buffers;
  // Cleared by close() before it stops streaming: from then on a buffer that
  // comes back from the pipeline is not queued again.
  std::atomic<bool> streaming{false};
  // The first errno of a failed requeue on a pipeline thread, reported by the
  // next wait_frame() on the capture thread.
  std::atomic<int> requeue_error{0};

 private:
  // The buffers are unmapped before the device is closed (fd_ goes after).
  ~Stream() {
    for (const auto& b : buffers) ::munmap(b.data, b.length);
  }

  UniqueFd fd_;
  std::atomic<int> references_{1};
};

// Holds the source's reference during open(), so that a failure part way
// closes everything opened so far.
class StreamHold {
 public:
  explicit StreamHold(Stream* stream) : stream_(stream) {}
  ~StreamHold() {
    if (stream_ != nullptr) stream_->release();
  }
  StreamHold(const StreamHold&) = delete;
  StreamHold& operator=(const StreamHold&) = delete;
  Stream* operator->() const { return stream_; }
  Stream& operator*() const { return *stream_; }
  Stream* give() { return std::exchange(stream_, nullptr); }

 private:
  Stream* stream_;
};

// A lent buffer's release hook (ReleaseHook::release), on whichever pipeline
// thread is last done with the frame.
void requeue_lent(void* context, std::uint64_t token) noexcept {
  auto* stream = static_cast<Stream*>(context);
  if (stream->streaming.load(std::memory_order_acquire)) {
    const int error = stream->queue(static_cast<std::uint32_t>(token));
    if (error != 0 && stream->streaming.load(std::memory_order_acquire)) {
      int none = 0;
      stream->requeue_error.compare_exchange_strong(none, error);
    }
  }
  stream->release();
}

Clock::time_point monotonic_time(const timeval& tv) {
  return Clock::time_point(std::chrono::duration_cast<Clock::duration>(std::chrono::seconds(tv.tv_sec) +
                                                                       std::chrono::microseconds(tv.tv_usec)));
}

// Bytes of a row the format's grey image reads: the Y bytes of a GREY or
// NV12 row, the Y and chroma bytes of a YUYV row; MJPEG has no rows.
std::size_t row_bytes(V4l2PixelFormat format, int width) {
  const auto w = static_cast<std::size_t>(width);
  switch (format) {
    case V4l2PixelFormat::grey:
    case V4l2PixelFormat::nv12: return w;
    case V4l2PixelFormat::yuyv: return 2 * w;
    case V4l2PixelFormat::mjpg: return 0;
  }
  return 0;
}

// ---------------------------------------------------------------- the source

class V4l2Source final : public CaptureSource {
 public:
  explicit V4l2Source(V4l2Settings settings)
      : settings_(std::move(settings)), name_("v4l2 " + settings_.device), label_(name_) {
    geometry_ = configured_geometry();
  }
  ~V4l2Source() override { V4l2Source::close(); }
  V4l2Source(const V4l2Source&) = delete;
  V4l2Source& operator=(const V4l2Source&) = delete;

  [[nodiscard]] const std::string& name() const override { return name_; }
  [[nodiscard]] CaptureGeometry geometry() const override { return geometry_; }
  [[nodiscard]] bool is_open() const noexcept override { return stream_ != nullptr; }

  void open() override;
  void close() noexcept override;
  [[nodiscard]] bool wait_frame(std::chrono::milliseconds timeout) override;
  void fill(Frame& frame) override;
  void skip() noexcept override;

 private:
  [[nodiscard]] CaptureGeometry configured_geometry() const {
    const bool converts = settings_.format == V4l2PixelFormat::yuyv || settings_.format == V4l2PixelFormat::mjpg;
    return {settings_.width, settings_.height,
            converts ? static_cast<std::size_t>(settings_.width) * static_cast<std::size_t>(settings_.height) : 0,
            settings_.fps};
  }

  [[nodiscard]] CaptureError error(Kind kind, std::string_view what) const {
    return {kind, fmt::format("{}: {}", label_, what)};
  }
  // An ioctl that failed on the open device: ENODEV is the device gone.
  [[nodiscard]] CaptureError ioctl_error(std::string_view ioctl, int error_number) const {
    const Kind kind = error_number == ENODEV ? Kind::vanished : Kind::io;
    return error(kind, fmt::format("{}: {}", ioctl, errno_text(error_number)));
  }

  void check_capabilities(int fd);
  void select_input(int fd, int input);
  void set_format(int fd);
  void set_frame_rate(int fd);
  void set_controls(int fd);
  void map_buffers(Stream& stream);
  bool dequeue();
  void requeue(std::uint32_t index);
  void publish_corrupt(Frame& frame, const char* cause, std::uint32_t index);

  V4l2Settings settings_;
  std::string name_;
  std::string label_;  // the name, and the node it resolved to when that differs
  CaptureGeometry geometry_;
  std::ptrdiff_t stride_ = 0;  // bytes per row of the mmap buffers
  std::size_t min_bytes_ = 0;  // what a buffer must hold for fill() to read the frame

  Stream* stream_ = nullptr;
  v4l2_buffer ready_{};
  bool has_ready_ = false;
  Clock::time_point ready_time_{};
  char cause_[Frame::kCauseCapacity] = {};
};

void V4l2Source::open() {
  close();
  geometry_ = configured_geometry();
  const fs::path path = resolve_v4l2_device(settings_.device);
  std::error_code ec;
  const fs::path node = fs::canonical(path, ec);
  label_ = !ec && node.string() != settings_.device ? fmt::format("{} ({})", name_, node.string()) : name_;

  UniqueFd device(::open(path.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC));
  if (!device) {
    const int e = errno;
    if (e == ENOENT || e == ENODEV || e == ENXIO) {
      throw error(Kind::not_found, fmt::format("cannot open {}: {} (not plugged in, or its driver not loaded)",
                                               path.string(), errno_text(e)));
    }
    throw error(Kind::io, fmt::format("cannot open {}: {}{}", path.string(), errno_text(e),
                                      e == EACCES ? " (is the user in the group that owns it, usually 'video'?)" : ""));
  }
  const int fd = device.get();
  StreamHold stream(new Stream(std::move(device)));
  check_capabilities(fd);
  if (settings_.input) select_input(fd, *settings_.input);
  set_format(fd);
  set_frame_rate(fd);
  set_controls(fd);
  map_buffers(*stream);
  for (std::uint32_t i = 0; i < stream->buffers.size(); ++i) {
    if (const int e = stream->queue(i); e != 0) throw ioctl_error(fmt::format("VIDIOC_QBUF buffer {}", i), e);
  }
  int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (xioctl(fd, VIDIOC_STREAMON, &type) != 0) throw ioctl_error("VIDIOC_STREAMON", errno);
  stream->streaming.store(true, std::memory_order_release);
  stream_ = stream.give();
}

void V4l2Source::check_capabilities(int fd) {
  v4l2_capability cap{};
  if (xioctl(fd, VIDIOC_QUERYCAP, &cap) != 0) {
    const int e = errno;
    if (e == ENOTTY || e == EINVAL) {
      throw error(Kind::config, fmt::format("not a V4L2 device (VIDIOC_QUERYCAP: {})", errno_text(e)));
    }
    throw ioctl_error("VIDIOC_QUERYCAP", e);
  }
  const std::uint32_t caps = device_caps(cap);
  const std::string what = fmt::format("'{}', driver {}", c_text(cap.card), c_text(cap.driver));
  if ((caps & V4L2_CAP_VIDEO_CAPTURE) == 0) {
    if ((caps & V4L2_CAP_VIDEO_CAPTURE_MPLANE) != 0) {
      throw error(Kind::config,
                  fmt::format("{} is a multi-planar capture device; markerd streams from single-planar ones", what));
    }
    throw error(Kind::config, fmt::format("{} is not a video capture device (a camera's other nodes are metadata "
                                          "or output: markerctl cameras lists the capture nodes)",
                                          what));
  }
  if ((caps & V4L2_CAP_STREAMING) == 0) {
    throw error(Kind::config, fmt::format("{} cannot stream (no V4L2_CAP_STREAMING)", what));
  }
}

void V4l2Source::select_input(int fd, int input) {
  if (xioctl(fd, VIDIOC_S_INPUT, &input) == 0) return;
  const int e = errno;
  if (e == EINVAL) {
    throw error(Kind::config, fmt::format("VIDIOC_S_INPUT {}: no such input (it has {})", input, input_list(fd)));
  }
  throw ioctl_error(fmt::format("VIDIOC_S_INPUT {}", input), e);
}

void V4l2Source::set_format(int fd) {
  const std::uint32_t fourcc = fourcc_of(settings_.format);
  const std::string asked = fmt::format("{} {}x{}", to_string(settings_.format), settings_.width, settings_.height);
  v4l2_format f{};
  f.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  f.fmt.pix.width = static_cast<std::uint32_t>(settings_.width);
  f.fmt.pix.height = static_cast<std::uint32_t>(settings_.height);
  f.fmt.pix.pixelformat = fourcc;
  f.fmt.pix.field = V4L2_FIELD_NONE;
  if (xioctl(fd, VIDIOC_S_FMT, &f) != 0) {
    const int e = errno;
    if (e == EINVAL) {
      throw error(Kind::config,
                  fmt::format("VIDIOC_S_FMT {}: {} (it offers {})", asked, errno_text(e), offered_formats(fd)));
    }
    if (e == EBUSY) {
      throw error(Kind::io,
                  fmt::format("VIDIOC_S_FMT {}: {} (another program is streaming from it)", asked, errno_text(e)));
    }
    throw ioctl_error(fmt::format("VIDIOC_S_FMT {}", asked), e);
  }
  const auto& pix = f.fmt.pix;
  if (pix.pixelformat != fourcc || static_cast<int>(pix.width) != settings_.width ||
      static_cast<int>(pix.height) != settings_.height) {
    throw error(Kind::config, fmt::format("VIDIOC_S_FMT: asked for {}, the device gives {} {}x{} (it offers {})", asked,
                                          fourcc_text(pix.pixelformat), pix.width, pix.height, offered_formats(fd)));
  }
  const std::size_t row = row_bytes(settings_.format, settings_.width);
  stride_ = static_cast<std::ptrdiff_t>(pix.bytesperline != 0 ? pix.bytesperline : row);
  if (static_cast<std::size_t>(stride_) < row) {
    throw error(Kind::io, fmt::format("VIDIOC_S_FMT {}: the driver gives rows of {} bytes, fewer than a row's {}",
                                      asked, stride_, row));
  }
  // The last row needs only its own bytes, not the padding after it.
  min_bytes_ = row == 0 ? 1 : static_cast<std::size_t>(stride_) * static_cast<std::size_t>(settings_.height - 1) + row;
  geometry_.width = settings_.width;
  geometry_.height = settings_.height;
}

void V4l2Source::set_frame_rate(int fd) {
  v4l2_streamparm parm{};
  parm.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (xioctl(fd, VIDIOC_G_PARM, &parm) != 0) {
    if (errno == ENODEV) throw ioctl_error("VIDIOC_G_PARM", ENODEV);
    if (settings_.fps > 0) {
      spdlog::warn("{}: cannot set the frame rate to {} fps: VIDIOC_G_PARM: {}", label_, settings_.fps,
                   errno_text(errno));
    }
    geometry_.frame_rate = 0;
    return;
  }
  auto& capture = parm.parm.capture;
  if (settings_.fps > 0 && (capture.capability & V4L2_CAP_TIMEPERFRAME) != 0) {
    capture.timeperframe = {1000, static_cast<std::uint32_t>(std::lround(settings_.fps * 1000))};
    if (xioctl(fd, VIDIOC_S_PARM, &parm) != 0) {
      throw ioctl_error(fmt::format("VIDIOC_S_PARM {} fps", settings_.fps), errno);
    }
  }
  const auto& tpf = capture.timeperframe;
  geometry_.frame_rate = tpf.numerator != 0 ? static_cast<double>(tpf.denominator) / tpf.numerator : 0;
  if (settings_.fps > 0 && std::abs(geometry_.frame_rate - settings_.fps) > 0.01 * settings_.fps) {
    spdlog::warn("{}: asked for {} fps, the device runs at {}", label_, settings_.fps,
                 geometry_.frame_rate > 0 ? fmt::format("{:.4g} fps", geometry_.frame_rate)
                                          : std::string("a rate it does not tell"));
  }
}

// The value to write for a configured control; a config error when the
// device's control cannot take it.
std::int64_t control_value(const V4l2ControlSetting& setting, const V4l2ControlInfo& c, const std::string& label) {
  const auto refuse = [&](const std::string& why) {
    return CaptureError(Kind::config, fmt::format("{}: control {} ({}): {}", label, setting.name, setting.origin, why));
  };
  const auto menu_text = [&] {
    std::string text;
    for (const auto& item : c.menu) text += fmt::format("{}{}: {}", text.empty() ? "" : ", ", item.index, item.name);
    return text;
  };
  if (std::find(c.flags.begin(), c.flags.end(), "read-only") != c.flags.end()) {
    throw refuse("the device's control is read-only");
  }
  if (c.type == "bool") {
    if (const auto* b = std::get_if<bool>(&setting.value)) return *b ? 1 : 0;
    if (const auto* i = std::get_if<std::int64_t>(&setting.value); i != nullptr && (*i == 0 || *i == 1)) return *i;
    throw refuse("a boolean control: give true or false");
  }
  if (c.type == "int" || c.type == "int64" || c.type == "bitmask") {
    const auto* i = std::get_if<std::int64_t>(&setting.value);
    if (i == nullptr) {
      throw refuse(fmt::format("an integer control ({} to {}): give a number", c.minimum, c.maximum));
    }
    if (c.type == "bitmask") {
      if ((static_cast<std::uint64_t>(*i) & ~static_cast<std::uint64_t>(c.maximum)) != 0) {
        throw refuse(fmt::format("{:#x} has bits outside the mask {:#x}", *i, c.maximum));
      }
      return *i;
    }
    if (*i < c.minimum || *i > c.maximum) {
      throw refuse(fmt::format("{} is out of its range {} to {}", *i, c.minimum, c.maximum));
    }
    if (c.step > 1 && static_cast<std::uint64_t>(*i - c.minimum) % c.step != 0) {
      throw refuse(fmt::format("{} is not on its steps: {} + a multiple of {}", *i, c.minimum, c.step));
    }
    return *i;
  }
  if (c.type == "menu" || c.type == "intmenu") {
    if (const auto* i = std::get_if<std::int64_t>(&setting.value)) {
      for (const auto& item : c.menu) {
        if (item.index == *i) return *i;
      }
      throw refuse(fmt::format("{} is not one of its items ({})", *i, menu_text()));
    }
    if (const auto* text = std::get_if<std::string>(&setting.value)) {
      for (const auto& item : c.menu) {
        if (lower(item.name) == lower(*text) || v4l2_control_name(item.name) == v4l2_control_name(*text)) {
          return item.index;
        }
      }
      throw refuse(fmt::format("'{}' is not one of its items ({})", *text, menu_text()));
    }
    throw refuse(fmt::format("a menu: give an item's number or name ({})", menu_text()));
  }
  if (c.type == "button") throw refuse("a button (an action, not a setting): it cannot be set from the config");
  throw refuse(fmt::format("a {} control: it cannot be set from the config", c.type));
}

void V4l2Source::set_controls(int fd) {
  if (settings_.controls.empty()) return;
  const auto controls = enum_controls(fd);
  const auto find = [&](const std::string& name) -> const V4l2ControlInfo* {
    for (const auto& c : controls) {
      if (c.name == name) return &c;
    }
    return nullptr;
  };
  // Automatic modes first: exposure_time_absolute is refused or ignored
  // while auto_exposure still says automatic, whatever order the file has.
  std::vector<const V4l2ControlSetting*> order;
  for (const auto& s : settings_.controls) order.push_back(&s);
  std::stable_partition(order.begin(), order.end(), [&](const V4l2ControlSetting* s) {
    const auto* c = find(s->name);
    return c != nullptr && lower(c->label).find("auto") != std::string::npos;
  });
  for (const auto* setting : order) {
    const auto* c = find(setting->name);
    if (c == nullptr) {
      std::string names;
      for (const auto& known : controls) names += fmt::format("{}{}", names.empty() ? "" : ", ", known.name);
      throw error(Kind::config, fmt::format("control {} ({}): the device has no such control (it has: {})",
                                            setting->name, setting->origin, names.empty() ? "none" : names));
    }
    const std::int64_t value = control_value(*setting, *c, label_);
    v4l2_ext_control control{};
    control.id = c->id;
    if (c->type == "int64") {
      control.value64 = value;
    } else {
      control.value = static_cast<std::int32_t>(value);
    }
    v4l2_ext_controls list{};
    list.which = V4L2_CTRL_WHICH_CUR_VAL;
    list.count = 1;
    list.controls = &control;
    int result = xioctl(fd, VIDIOC_S_EXT_CTRLS, &list);
    if (result != 0 && errno == ENOTTY && c->type != "int64") {
      v4l2_control old{c->id, static_cast<std::int32_t>(value)};
      result = xioctl(fd, VIDIOC_S_CTRL, &old);
    }
    if (result != 0) {
      const int e = errno;
      const std::string what = fmt::format("control {} ({}) = {}: VIDIOC_S_EXT_CTRLS: {}", setting->name,
                                           setting->origin, value, errno_text(e));
      if (e == EACCES) throw error(Kind::config, what + " (the device refuses it now: an automatic mode holds it?)");
      if (e == EINVAL || e == ERANGE) throw error(Kind::config, what);
      throw error(e == ENODEV ? Kind::vanished : Kind::io, what);
    }
  }
}

void V4l2Source::map_buffers(Stream& stream) {
  v4l2_requestbuffers request{};
  request.count = static_cast<std::uint32_t>(settings_.buffers);
  request.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  request.memory = V4L2_MEMORY_MMAP;
  if (xioctl(stream.fd(), VIDIOC_REQBUFS, &request) != 0) {
    const int e = errno;
    if (e == EINVAL) {
      throw error(Kind::config, fmt::format("VIDIOC_REQBUFS {}: {} (it cannot stream through mmap buffers)",
                                            settings_.buffers, errno_text(e)));
    }
    if (e == EBUSY) {
      throw error(Kind::io, fmt::format("VIDIOC_REQBUFS {}: {} (another program is streaming from it)",
                                        settings_.buffers, errno_text(e)));
    }
    throw ioctl_error(fmt::format("VIDIOC_REQBUFS {}", settings_.buffers), e);
  }
  if (request.count == 0) throw error(Kind::io, "VIDIOC_REQBUFS: the driver gave no buffers");
  stream.buffers.reserve(request.count);
  for (std::uint32_t i = 0; i < request.count; ++i) {
    v4l2_buffer buffer{};
    buffer.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buffer.memory = V4L2_MEMORY_MMAP;
    buffer.index = i;
    if (xioctl(stream.fd(), VIDIOC_QUERYBUF, &buffer) != 0) {
      throw ioctl_error(fmt::format("VIDIOC_QUERYBUF buffer {}", i), errno);
    }
    if (buffer.length < min_bytes_) {
      throw error(Kind::io, fmt::format("buffer {} holds {} bytes, fewer than a {} frame's {}", i, buffer.length,
                                        to_string(settings_.format), min_bytes_));
    }
    void* data = ::mmap(nullptr, buffer.length, PROT_READ, MAP_SHARED, stream.fd(), buffer.m.offset);
    if (data == MAP_FAILED) throw ioctl_error(fmt::format("mmap buffer {}", i), errno);
    stream.buffers.push_back({static_cast<std::uint8_t*>(data), buffer.length});
  }
}

void V4l2Source::close() noexcept {
  has_ready_ = false;
  if (stream_ == nullptr) return;
  stream_->streaming.store(false, std::memory_order_release);
  // Both fail with ENODEV on a device that is gone, which changes nothing.
  int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  xioctl(stream_->fd(), VIDIOC_STREAMOFF, &type);
  // Gives up the queue, so that the next open() can take it while frames
  // still borrow these buffers: videobuf2 keeps the memory of a buffer that
  // is still mapped (it orphans it) until the mapping goes.
  v4l2_requestbuffers none{};
  none.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  none.memory = V4L2_MEMORY_MMAP;
  xioctl(stream_->fd(), VIDIOC_REQBUFS, &none);
  std::exchange(stream_, nullptr)->release();
}

bool V4l2Source::dequeue() {
  v4l2_buffer buffer{};
  buffer.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  buffer.memory = V4L2_MEMORY_MMAP;
  if (xioctl(stream_->fd(), VIDIOC_DQBUF, &buffer) != 0) {
    const int e = errno;
    if (e == EAGAIN) return false;
    if (e == EIO) throw error(Kind::io, "VIDIOC_DQBUF: the driver reports a streaming error (EIO)");
    throw ioctl_error("VIDIOC_DQBUF", e);
  }
  if (buffer.index >= stream_->buffers.size()) {
    throw error(Kind::io, fmt::format("VIDIOC_DQBUF: buffer index {} of {}", buffer.index, stream_->buffers.size()));
  }
  ready_ = buffer;
  ready_time_ = Clock::now();
  has_ready_ = true;
  return true;
}

bool V4l2Source::wait_frame(std::chrono::milliseconds timeout) {
  if (stream_ == nullptr) throw std::logic_error(name_ + ": wait_frame() while not open");
  if (has_ready_) return true;
  if (const int e = stream_->requeue_error.exchange(0); e != 0) {
    throw ioctl_error("VIDIOC_QBUF of a buffer back from the pipeline", e);
  }
  const auto deadline = Clock::now() + timeout;
  for (;;) {
    // A frame may be done already: then there is no need to poll.
    if (dequeue()) return true;
    const auto left = std::chrono::ceil<std::chrono::milliseconds>(deadline - Clock::now());
    if (left.count() <= 0) return false;
    pollfd p{stream_->fd(), POLLIN, 0};
    const int n = ::poll(&p, 1, static_cast<int>(left.count()));
    if (n < 0) {
      if (errno == EINTR) continue;
      throw ioctl_error("poll", errno);
    }
    if (n == 0) return false;
    if ((p.revents & POLLIN) == 0 && (p.revents & (POLLERR | POLLHUP | POLLNVAL)) != 0) {
      if (dequeue()) return true;
      // videobuf2 and the V4L2 core say POLLERR when the device is
      // unregistered or the queue stopped; DQBUF normally names which.
      throw error(Kind::vanished, fmt::format("poll reports {} and no frame is ready: the device stopped streaming "
                                              "or went away",
                                              (p.revents & POLLHUP) != 0 ? "POLLHUP" : "POLLERR"));
    }
  }
}

void V4l2Source::requeue(std::uint32_t index) {
  if (const int e = stream_->queue(index); e != 0) throw ioctl_error("VIDIOC_QBUF", e);
}

void V4l2Source::publish_corrupt(Frame& frame, const char* cause, std::uint32_t index) {
  frame.mark_corrupt(cause);
  requeue(index);
}

void V4l2Source::fill(Frame& frame) {
  if (!has_ready_) throw std::logic_error(name_ + ": fill() without a frame from wait_frame()");
  has_ready_ = false;
  const v4l2_buffer& b = ready_;
  frame.sequence = b.sequence;
  frame.capture_time = (b.flags & V4L2_BUF_FLAG_TIMESTAMP_MASK) == V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC
                           ? monotonic_time(b.timestamp)
                           : ready_time_;
  const MappedBuffer& buffer = stream_->buffers[b.index];
  const std::size_t bytes = std::min<std::size_t>(b.bytesused, buffer.length);
  if ((b.flags & V4L2_BUF_FLAG_ERROR) != 0) {
    publish_corrupt(frame, "the driver marked the frame broken (V4L2_BUF_FLAG_ERROR)", b.index);
    return;
  }
  if (bytes < min_bytes_) {
    std::snprintf(cause_, sizeof cause_, "short frame: %zu bytes, a %dx%d %s frame needs %zu", bytes, settings_.width,
                  settings_.height, to_string(settings_.format).data(), min_bytes_);
    publish_corrupt(frame, cause_, b.index);
    return;
  }
  const int w = settings_.width;
  const int h = settings_.height;
  if (settings_.format == V4l2PixelFormat::grey || settings_.format == V4l2PixelFormat::nv12) {
    // The grey image is the buffer itself (NV12's Y plane comes first).
    frame.image = GreyView{buffer.data, w, h, stride_};
    stream_->retain();
    frame.set_release({&requeue_lent, stream_, b.index});
    return;
  }
  try {
    frame.use_pixel_buffer(w, h);
  } catch (const std::length_error& e) {
    // The frame pool was made for another size: no reopen mends that.
    stream_->queue(b.index);
    throw error(Kind::config, e.what());
  }
  if (settings_.format == V4l2PixelFormat::mjpg) {
    // Lent still encoded: the worker that detects the frame decodes it into
    // the slot's pixels and gives the buffer back (Frame::set_encoded).
    frame.set_encoded({buffer.data, bytes}, &decode_mjpeg_frame);
    stream_->retain();
    frame.set_release({&requeue_lent, stream_, b.index});
    return;
  }
  yuyv_to_grey(buffer.data, stride_, w, h, frame.pixel_buffer().data(), w);
  requeue(b.index);
}

void V4l2Source::skip() noexcept {
  if (!has_ready_ || stream_ == nullptr) return;
  has_ready_ = false;
  if (const int e = stream_->queue(ready_.index); e != 0) {
    int none = 0;
    stream_->requeue_error.compare_exchange_strong(none, e);
  }
}

// ---------------------------------------------------------------- listing helpers

// node (canonical) -> the by-id and by-path links that point at it.
std::map<std::string, std::vector<std::string>> stable_links(const fs::path& dev_dir) {
  std::map<std::string, std::vector<std::string>> links;
  for (const char* kind : {"by-id", "by-path"}) {
    std::error_code ec;
    for (fs::directory_iterator it(dev_dir / "v4l" / kind, ec), end; !ec && it != end; it.increment(ec)) {
      std::error_code link_ec;
      if (!it->is_symlink(link_ec)) continue;
      const fs::path target = fs::canonical(it->path(), link_ec);
      if (link_ec) continue;
      links[target.string()].push_back(it->path().string());
    }
  }
  for (auto& [node, names] : links) std::sort(names.begin(), names.end());
  return links;
}

V4l2DeviceInfo describe(const fs::path& path, const std::map<std::string, std::vector<std::string>>& links,
                        bool& capture) {
  capture = false;
  V4l2DeviceInfo info;
  info.path = path.string();
  std::error_code ec;
  if (const fs::path node = fs::canonical(path, ec); !ec) {
    if (const auto it = links.find(node.string()); it != links.end()) info.stable_names = it->second;
  }
  UniqueFd device(::open(path.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC));
  if (!device && errno == EACCES) device.reset(::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC));
  if (!device) {
    info.error = fmt::format("cannot open: {}", errno_text(errno));
    capture = true;  // it may be one; the error says why it is not described
    return info;
  }
  const int fd = device.get();
  v4l2_capability cap{};
  if (xioctl(fd, VIDIOC_QUERYCAP, &cap) != 0) {
    info.error = fmt::format("not a V4L2 device (VIDIOC_QUERYCAP: {})", errno_text(errno));
    capture = true;
    return info;
  }
  info.driver = c_text(cap.driver);
  info.card = c_text(cap.card);
  info.bus_info = c_text(cap.bus_info);
  const std::uint32_t caps = device_caps(cap);
  if ((caps & (V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_VIDEO_CAPTURE_MPLANE)) == 0) {
    info.error = "not a video capture device";
    return info;
  }
  capture = true;
  info.multiplanar = (caps & V4L2_CAP_VIDEO_CAPTURE) == 0;
  const std::uint32_t type = info.multiplanar ? V4L2_BUF_TYPE_VIDEO_CAPTURE_MPLANE : V4L2_BUF_TYPE_VIDEO_CAPTURE;
  info.inputs = enum_inputs(fd);
  if (int input = 0; xioctl(fd, VIDIOC_G_INPUT, &input) == 0) info.current_input = static_cast<std::uint32_t>(input);
  v4l2_format f{};
  f.type = type;
  if (xioctl(fd, VIDIOC_G_FMT, &f) == 0) {
    if (info.multiplanar) {
      info.current_format = fourcc_text(f.fmt.pix_mp.pixelformat);
      info.current_width = f.fmt.pix_mp.width;
      info.current_height = f.fmt.pix_mp.height;
    } else {
      info.current_format = fourcc_text(f.fmt.pix.pixelformat);
      info.current_width = f.fmt.pix.width;
      info.current_height = f.fmt.pix.height;
    }
  }
  v4l2_streamparm parm{};
  parm.type = type;
  if (xioctl(fd, VIDIOC_G_PARM, &parm) == 0 && parm.parm.capture.timeperframe.numerator != 0) {
    info.current_fps =
        static_cast<double>(parm.parm.capture.timeperframe.denominator) / parm.parm.capture.timeperframe.numerator;
  }
  info.formats = enum_formats(fd, type);
  info.controls = enum_controls(fd);
  return info;
}

nlohmann::ordered_json fraction_json(const V4l2Fraction& f) {
  nlohmann::ordered_json j{{"numerator", f.numerator}, {"denominator", f.denominator}};
  if (f.numerator != 0) j["fps"] = std::round(1000.0 * f.denominator / f.numerator) / 1000.0;
  return j;
}

nlohmann::ordered_json intervals_json(const V4l2Intervals& intervals) {
  nlohmann::ordered_json j = nlohmann::ordered_json::object();
  if (!intervals.discrete.empty() || !intervals.min) {
    j["discrete"] = nlohmann::ordered_json::array();
    for (const auto& f : intervals.discrete) j["discrete"].push_back(fraction_json(f));
  }
  if (intervals.min) j["min"] = fraction_json(*intervals.min);
  if (intervals.max) j["max"] = fraction_json(*intervals.max);
  if (intervals.step) j["step"] = fraction_json(*intervals.step);
  return j;
}

}  // namespace

// ---------------------------------------------------------------- public functions

V4l2Settings parse_v4l2_settings(const ConfigTable& table) {
  table.allow_only({"device", "format", "width", "height", "fps", "buffers", "input", "controls"});
  V4l2Settings s;
  s.device = table.required<std::string>("device");
  if (s.device.empty()) {
    table.fail("device", "must not be empty (a path such as /dev/video0, or a /dev/v4l/by-id name)");
  }

  const auto format = table.optional<std::string>("format", "YUYV");
  const std::string upper = [&] {
    std::string u = format;
    std::transform(u.begin(), u.end(), u.begin(), [](unsigned char c) { return std::toupper(c); });
    return u;
  }();
  if (upper == "GREY") {
    s.format = V4l2PixelFormat::grey;
  } else if (upper == "YUYV") {
    s.format = V4l2PixelFormat::yuyv;
  } else if (upper == "NV12") {
    s.format = V4l2PixelFormat::nv12;
  } else if (upper == "MJPG" || upper == "MJPEG") {
    s.format = V4l2PixelFormat::mjpg;
  } else {
    table.fail("format", fmt::format("unknown format '{}' (use GREY, YUYV, NV12 or MJPG)", format));
  }

  constexpr int kMaxSide = 16384;
  s.width = table.required<int>("width");
  if (s.width <= 0 || s.width > kMaxSide) {
    table.fail("width", fmt::format("must be 1 to {}, got {}", kMaxSide, s.width));
  }
  if (s.format == V4l2PixelFormat::yuyv && s.width % 2 != 0) {
    table.fail("width", fmt::format("must be even for YUYV (two pixels share their chroma), got {}", s.width));
  }
  s.height = table.required<int>("height");
  if (s.height <= 0 || s.height > kMaxSide) {
    table.fail("height", fmt::format("must be 1 to {}, got {}", kMaxSide, s.height));
  }
  s.fps = table.optional<double>("fps", 0.0);
  if (table.contains("fps") && !(s.fps > 0 && s.fps <= 1000)) {
    table.fail("fps", fmt::format("must be > 0 and at most 1000 frames per second, got {}", s.fps));
  }
  s.buffers = table.optional<int>("buffers", 4);
  if (s.buffers < 2 || s.buffers > 32) {
    table.fail("buffers", fmt::format("must be 2 to 32, got {} (one is always with the driver)", s.buffers));
  }
  if (const auto input = table.maybe<std::int64_t>("input")) {
    // VIDIOC_S_INPUT takes any index; a driver has a handful of inputs.
    if (*input < 0 || *input > 255) {
      table.fail("input", fmt::format("must be an input's index, 0 to 255, got {}", *input));
    }
    s.input = static_cast<int>(*input);
  }

  if (const auto controls = table.maybe_table("controls")) {
    for (const auto& [key, node] : controls->raw()) {
      const std::string name(key.str());
      if (name.empty() || v4l2_control_name(name) != name) {
        controls->fail(name, fmt::format("write control names as v4l2-ctl prints them: '{}'", v4l2_control_name(name)));
      }
      V4l2ControlSetting setting;
      setting.name = name;
      if (const auto i = node.value_exact<std::int64_t>()) {
        setting.value = *i;
      } else if (const auto b = node.value_exact<bool>()) {
        setting.value = *b;
      } else if (const auto text = node.value_exact<std::string>()) {
        setting.value = *text;
      } else {
        controls->fail(name, "must be an integer, a boolean, or the name of a menu item");
      }
      const auto line = node.source().begin.line;
      setting.origin = line > 0 ? fmt::format("{}:{}: {}.{}", controls->source(), line, controls->key_path(), name)
                                : fmt::format("{}: {}.{}", controls->source(), controls->key_path(), name);
      s.controls.push_back(std::move(setting));
    }
  }
  return s;
}

std::unique_ptr<CaptureSource> make_v4l2_source(const V4l2Settings& settings) {
  return std::make_unique<V4l2Source>(settings);
}

fs::path resolve_v4l2_device(std::string_view device, const fs::path& dev_dir) {
  if (device.empty()) throw CaptureError(Kind::config, "v4l2: no device given");
  if (device.find('/') != std::string_view::npos) return fs::path(device);
  std::vector<fs::path> tried;
  for (const fs::path& dir : {dev_dir / "v4l" / "by-id", dev_dir / "v4l" / "by-path", dev_dir}) {
    fs::path candidate = dir / device;
    std::error_code ec;
    if (fs::exists(fs::symlink_status(candidate, ec))) return candidate;
    tried.push_back(std::move(candidate));
  }
  throw CaptureError(Kind::not_found,
                     fmt::format("v4l2 {}: no such device: none of {}, {}, {} exists (not plugged in, or named "
                                 "otherwise: markerctl cameras lists the names)",
                                 device, tried[0].string(), tried[1].string(), tried[2].string()));
}

std::vector<V4l2DeviceInfo> list_v4l2_devices(const fs::path& dev_dir) {
  std::vector<std::pair<unsigned long, fs::path>> nodes;
  std::error_code ec;
  for (fs::directory_iterator it(dev_dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string file = it->path().filename().string();
    if (file.size() <= 5 || file.compare(0, 5, "video") != 0) continue;
    unsigned long number = 0;
    const auto [rest, parse_error] = std::from_chars(file.data() + 5, file.data() + file.size(), number);
    if (parse_error != std::errc{} || rest != file.data() + file.size()) continue;
    nodes.emplace_back(number, it->path());
  }
  std::sort(nodes.begin(), nodes.end());
  const auto links = stable_links(dev_dir);
  std::vector<V4l2DeviceInfo> devices;
  for (const auto& [number, path] : nodes) {
    bool capture = false;
    auto info = describe(path, links, capture);
    if (capture) devices.push_back(std::move(info));
  }
  return devices;
}

V4l2DeviceInfo describe_v4l2_device(const fs::path& path, const fs::path& dev_dir) {
  bool capture = false;
  return describe(path, stable_links(dev_dir), capture);
}

nlohmann::ordered_json to_json(const V4l2DeviceInfo& d) {
  using json = nlohmann::ordered_json;
  json j{{"backend", "v4l2"}, {"path", d.path}, {"stable_names", d.stable_names}};
  if (!d.error.empty()) {
    j["error"] = d.error;
    if (d.driver.empty()) return j;
  }
  j["driver"] = d.driver;
  j["card"] = d.card;
  j["bus_info"] = d.bus_info;
  if (!d.error.empty()) return j;
  j["multiplanar"] = d.multiplanar;
  j["inputs"] = json::array();
  for (const auto& input : d.inputs) {
    j["inputs"].push_back({{"index", input.index}, {"name", input.name}, {"type", input.type}});
  }
  j["current_input"] = d.current_input ? json(*d.current_input) : json(nullptr);
  j["current"] = {{"format", d.current_format},
                  {"width", d.current_width},
                  {"height", d.current_height},
                  {"fps", std::round(d.current_fps * 1000.0) / 1000.0}};
  j["formats"] = json::array();
  for (const auto& f : d.formats) {
    json format{{"fourcc", f.fourcc_text}, {"description", f.description}};
    if (f.compressed) format["compressed"] = true;
    if (f.emulated) format["emulated"] = true;
    format["sizes"] = json::array();
    for (const auto& size : f.sizes) {
      format["sizes"].push_back(
          {{"width", size.width}, {"height", size.height}, {"intervals", intervals_json(size.intervals)}});
    }
    if (f.size_range) {
      const auto& r = *f.size_range;
      format["size_range"] = {{"min_width", r.min_width},   {"max_width", r.max_width},
                              {"step_width", r.step_width}, {"min_height", r.min_height},
                              {"max_height", r.max_height}, {"step_height", r.step_height}};
    }
    j["formats"].push_back(std::move(format));
  }
  j["controls"] = json::array();
  for (const auto& c : d.controls) {
    json control{{"name", c.name},   {"label", c.label}, {"id", c.id},     {"type", c.type},
                 {"min", c.minimum}, {"max", c.maximum}, {"step", c.step}, {"default", c.default_value}};
    control["value"] = c.value ? json(*c.value) : json(nullptr);
    control["flags"] = c.flags;
    if (!c.menu.empty()) {
      control["menu"] = json::array();
      for (const auto& item : c.menu) control["menu"].push_back({{"index", item.index}, {"name", item.name}});
    }
    j["controls"].push_back(std::move(control));
  }
  return j;
}

}  // namespace markerd::daemon
