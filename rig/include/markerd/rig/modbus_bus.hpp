#pragma once
// One Modbus bus (an RS-485 line in RTU mode, or a TCP connection) and the one
// thread that owns it. A libmodbus context is not thread-safe, and an RS-485
// line carries one transaction at a time, so every drive on the bus hands its
// work to this thread: commands through execute() (queued, in order), its
// status poll as a callback run every poll period, and its emergency stop as
// an urgent callback that runs ahead of everything queued.
//
// Every request is retried a bounded number of times: on a timeout, a bad
// frame (CRC error, reply from the wrong unit, malformed reply) or an
// exception reply, the bus discards what is left on the line and sends the
// request again; after the last attempt the operation throws a DriveError
// naming the bus, the unit id, the function and register, and the cause. A
// TCP bus whose connection drops reconnects on the next attempt; an RTU bus
// whose device vanished (a USB adapter unplugged) reopens it the same way.

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>

#include "markerd/base/config_table.hpp"
#include "markerd/rig/drive.hpp"
#include "markerd/rig/register_map.hpp"

namespace markerd::rig {

enum class ModbusTransport : std::uint8_t { rtu, tcp };

struct ModbusBusSettings {
  std::string name;  // the key of [rig.buses.<name>], for messages
  ModbusTransport transport = ModbusTransport::rtu;
  // RTU
  std::string device;
  int baud = 19200;
  char parity = 'E';  // 'N', 'E' or 'O'
  int data_bits = 8;
  int stop_bits = 1;
  // TCP
  std::string host = "127.0.0.1";
  int port = 502;
  // How long to wait for the first byte of a reply, and between its bytes
  // (0: no byte timeout).
  std::chrono::milliseconds response_timeout{100};
  std::chrono::milliseconds byte_timeout{20};
  int retries = 2;  // extra attempts after the first
  std::chrono::milliseconds poll_period{50};

  // "rtu0 (/dev/ttyUSB0, 19200 8E1)", "tcp0 (192.168.0.20:502)".
  [[nodiscard]] std::string describe() const;
};

// Parses [rig.buses.<name>]; the name is the table's own key. ConfigError
// naming file:line:key.
ModbusBusSettings parse_modbus_bus(const ConfigTable& bus_table);

// The operations a drive's work can do on the bus thread. All retry as
// described above and then throw DriveError. `attempts` overrides the bus's
// retries + 1 (1: a single try, for best-effort writes to a drive already
// known to be unreachable).
class ModbusLink {
 public:
  virtual ~ModbusLink() = default;
  virtual void read_registers(int unit, RegisterTable table, std::uint16_t address, std::span<std::uint16_t> out,
                              int attempts = 0) = 0;
  virtual void read_bits(int unit, RegisterTable table, std::uint16_t address, std::span<std::uint8_t> out,
                         int attempts = 0) = 0;
  // FC06 for one register unless fc16_for_single, else FC16.
  virtual void write_registers(int unit, std::uint16_t address, std::span<const std::uint16_t> values,
                               bool fc16_for_single = false, int attempts = 0) = 0;
  virtual void write_coil(int unit, std::uint16_t address, bool on, int attempts = 0) = 0;
  [[nodiscard]] virtual const std::string& description() const = 0;
};

class ModbusBus {
 public:
  // Opens the serial device or connects, then starts the bus thread.
  // DriveError when the device cannot be opened or the server cannot be
  // reached; std::invalid_argument for settings libmodbus refuses.
  explicit ModbusBus(ModbusBusSettings settings);
  ~ModbusBus();  // finishes the request in progress, fails the queued ones, joins
  ModbusBus(const ModbusBus&) = delete;
  ModbusBus& operator=(const ModbusBus&) = delete;

  [[nodiscard]] const ModbusBusSettings& settings() const;
  [[nodiscard]] const std::string& description() const;  // settings().describe()

  using Work = std::function<void(ModbusLink&)>;
  // Runs `work` on the bus thread and waits for it; its exception is rethrown
  // here. Called from the bus thread itself (a poll callback), it runs at once.
  void execute(const Work& work);

  // A drive attached to the bus: `poll` runs once every poll period, `urgent`
  // whenever request_urgent() asks for it, before anything queued and between
  // the attempts of a request in progress. Callbacks must not throw.
  struct Client {
    Work poll;
    Work urgent;
  };
  using ClientId = std::uint32_t;
  ClientId attach(Client client);
  // Returns once the bus thread runs none of the client's callbacks and never
  // will again.
  void detach(ClientId id);
  // Never blocks on the line: marks the client's urgent work and wakes the bus
  // thread. Callable from any thread.
  void request_urgent(ClientId id) noexcept;

  struct Counters {
    std::uint64_t requests = 0;    // Modbus requests sent, retries included
    std::uint64_t retries = 0;     // attempts after a failed one
    std::uint64_t failures = 0;    // operations that failed after their last attempt
    std::uint64_t reconnects = 0;  // connections (re)opened after the first
  };
  [[nodiscard]] Counters counters() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace markerd::rig
