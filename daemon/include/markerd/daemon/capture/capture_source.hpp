#pragma once
// One interface for every camera backend (V4L2, libcamera, file, simulated).
// A CaptureSource is driven by one thread, the capture loop
// (capture_loop.hpp), which owns its open/close cycle and feeds its frames
// into the pipeline:
//
//   source.open();                                   // CaptureError on failure
//   for (;;) {
//     if (!source.wait_frame(timeout)) { stalled; }  // nothing within the timeout
//     Frame* slot = pipeline.acquire(stop);
//     if (!slot) { source.skip(); continue; }        // live pipeline: dropped
//     source.fill(*slot);                            // lends or writes the pixels
//     pipeline.publish(*slot);                       // a worker decodes an encoded frame
//   }
//   source.close();
//
// Whoever takes frames from fill() without a pipeline calls Frame::decode()
// first: an MJPEG frame comes out of fill() still encoded.
//
// A failure of the device (it vanished, a read failed) is thrown as a
// CaptureError naming the device and the cause; the loop closes the source
// and opens it again with backoff. A frame that cannot be read (a broken
// MJPEG, a short buffer) is not a failure of the device: fill() (or, for an
// MJPEG frame, decode()) marks it corrupt_frame with the cause, so the log
// records it.

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "markerd/daemon/capture/camera_controls.hpp"
#include "markerd/daemon/frame.hpp"

namespace markerd::daemon {

class CaptureError : public std::runtime_error {
 public:
  enum class Kind : std::uint8_t {
    config,     // the device cannot do what the config asks (format, size, control): reopening will not help
    not_found,  // no such device (yet): unplugged, driver not loaded
    vanished,   // it was there and went away while open (ENODEV)
    io,         // any other failure of the device or its driver
  };
  CaptureError(Kind kind, const std::string& message) : std::runtime_error(message), kind_(kind) {}
  [[nodiscard]] Kind kind() const noexcept { return kind_; }

 private:
  Kind kind_;
};
[[nodiscard]] std::string_view to_string(CaptureError::Kind kind);

// What a source delivers once open: the grey image's size, and what a frame
// slot must hold for it.
struct CaptureGeometry {
  int width = 0;
  int height = 0;
  // Pixel bytes a frame slot needs: width * height for sources that write
  // the grey image into the slot (a conversion, a renderer), 0 for sources
  // that lend their own buffers. Known before open() (from the config), since
  // the frame pool is allocated once, before the first open.
  std::size_t slot_pixel_bytes = 0;
  double frame_rate = 0;  // frames per second it was set up for; 0: as fast as it can
};

class CaptureSource {
 public:
  virtual ~CaptureSource() = default;

  // "v4l2 /dev/v4l/by-id/usb-...-video-index0", "sim 1280x960@30": names the
  // source in logs, errors and the control socket's status.
  [[nodiscard]] virtual const std::string& name() const = 0;
  // The size of the frames it will deliver, from the config; what open()
  // negotiated once open.
  [[nodiscard]] virtual CaptureGeometry geometry() const = 0;

  // Opens the device, sets it up as configured and starts streaming. Throws
  // CaptureError. Called again after close() to reopen.
  virtual void open() = 0;
  // Stops streaming and closes the device; safe when not open. Frames whose
  // pixels the source lent may still be in the pipeline: their release
  // hooks can run after close() (on another thread), and the memory they
  // point at must stay valid until they have.
  virtual void close() noexcept = 0;
  [[nodiscard]] virtual bool is_open() const noexcept = 0;

  // Waits up to `timeout` for the next frame: true when one is ready (fill()
  // or skip() must come next), false when none came. Throws CaptureError.
  // A source with a frame rate of its own (simulated, file) returns at that
  // rate; the file source returns false forever once a file without `loop`
  // has ended (see at_end()).
  [[nodiscard]] virtual bool wait_frame(std::chrono::milliseconds timeout) = 0;
  // Puts the ready frame into `frame`: sequence, capture_time (the driver's
  // timestamp when there is one), image (lent with a release hook, or written
  // into frame.pixel_buffer()), or status corrupt_frame and a cause. Sets
  // neither source_id nor rig: the capture loop does. Throws CaptureError
  // when the device fails; the frame then goes back unpublished.
  virtual void fill(Frame& frame) = 0;
  // Gives the ready frame back without using it (the pipeline dropped it).
  virtual void skip() noexcept = 0;

  // True once a finite source (a file source without `loop`) has delivered
  // its last frame.
  [[nodiscard]] virtual bool at_end() const noexcept { return false; }

  // ---- controls at run time (camera.get, camera.set; camera_controls.hpp) ----
  // Any thread (the control server's) while the capture thread streams: a
  // backend guards its device itself, and never holds up wait_frame() or
  // fill() for it. A value written lasts until markerd stops: a reopen of
  // the camera sets it again after the config's.

  // Every control with its value now. CaptureError when the controls cannot
  // be read (the camera is not open). A source without controls has none.
  [[nodiscard]] virtual std::vector<CameraControlInfo> read_controls() { return {}; }
  // Writes one control, as read_controls() described it, with a value
  // check_control_value() took. CaptureError when the device refuses it.
  virtual void write_control(const CameraControlInfo& control, const ControlValue& value);
};

}  // namespace markerd::daemon
