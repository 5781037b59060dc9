// The round trip of a Modbus move command, against the simulated drive
// (ModbusDriveSim, generic map) over loopback TCP and over RTU through a socat
// pty pair configured for 115200 baud 8E1. Every move has zero length, so the
// figure is the protocol's, not the motion's.
//
//   BM_ProtocolRoundTrip: on the bus thread, write target, velocity, ramps and
//     the start command (one FC16 of 9 registers), then read the status (FC04
//     of 4 registers) until in position: the wire cost of a move.
//   BM_DriveRoundTrip: the same through ModbusDrive, as an Axis sees it:
//     start_move() returns after the write, then status() is watched until
//     the bus thread's poll (every 1 ms here) has seen the move end.
//
// A pty does not pace bytes at the configured baud rate: the RTU figures are
// the pty's and the two processes' latency. On a real 115200-baud line add
// the bytes' time on the wire: 27 + 8 bytes for the FC16 request and reply,
// 8 + 13 for the FC04, 11 bits each (8E1): 5.3 ms, plus the drive's own
// turnaround.

#include <benchmark/benchmark.h>

#include <filesystem>
#include <memory>
#include <optional>
#include <thread>

#include "markerd/rig/modbus_bus.hpp"
#include "markerd/rig/modbus_drive.hpp"
#include "markerd/rig/register_map.hpp"
#include "markerd/rig/testing/modbus_drive_sim.hpp"
#include "modbus/peers.hpp"

using namespace markerd::rig;

namespace {

const std::filesystem::path kSourceDir = MARKERD_SOURCE_DIR;

// A simulated drive (unit 1) and a bus to it, over TCP or an RTU pty pair.
struct Peer {
  markerd::test_support::TempDir dir;
  std::optional<markerd::test_support::SocatPtyPair> line;
  RegisterMap map = load_register_map(kSourceDir / "config/drives/generic.toml");
  std::unique_ptr<ModbusDriveSim> sim;
  std::shared_ptr<ModbusBus> bus;

  explicit Peer(bool rtu, std::chrono::milliseconds poll_period) {
    ModbusSimUnit unit;
    unit.unit_id = 1;
    unit.map = map;
    unit.homed = true;
    unit.enabled = true;
    ModbusBusSettings s;
    s.response_timeout = std::chrono::milliseconds(500);
    s.byte_timeout = std::chrono::milliseconds(50);
    s.poll_period = poll_period;
    if (rtu) {
      line.emplace(dir.path());
      sim = std::make_unique<ModbusDriveSim>(std::vector{unit}, ModbusSimRtu{line->b().string(), 115200, 'E', 8, 1});
      s.name = "rtu";
      s.transport = ModbusTransport::rtu;
      s.device = line->a().string();
      s.baud = 115200;
    } else {
      sim = std::make_unique<ModbusDriveSim>(std::vector{unit}, ModbusSimTcp{});
      s.name = "tcp";
      s.transport = ModbusTransport::tcp;
    }
    sim->start();
    if (!rtu) s.port = sim->port();
    bus = std::make_shared<ModbusBus>(s);
  }
};

void report(benchmark::State& state, const ModbusBus& bus, const ModbusBus::Counters& before) {
  const auto after = bus.counters();
  state.counters["requests/move"] =
      static_cast<double>(after.requests - before.requests) / static_cast<double>(state.iterations());
  state.counters["retries"] = static_cast<double>(after.retries - before.retries);
}

void BM_ProtocolRoundTrip(benchmark::State& state, bool rtu) {
  Peer peer(rtu, std::chrono::seconds(1));
  const RegisterMap& m = peer.map;
  std::uint16_t move[9] = {};
  // Target 0 (where the drive stands), 100000 steps/s, 1e6 steps/s^2.
  m.target_position.pack(0, std::span(move, 2));
  m.velocity.pack(100000, std::span(move + 2, 2));
  m.acceleration.pack(1000000, std::span(move + 4, 2));
  m.deceleration->pack(1000000, std::span(move + 6, 2));
  move[8] = static_cast<std::uint16_t>(m.start.write.value);
  const int in_position = *m.status.in_position;
  const auto before = peer.bus->counters();
  for (auto _ : state) {
    peer.bus->execute([&](ModbusLink& link) {
      link.write_registers(1, 0x0000, move);
      std::uint16_t status[4] = {};
      do {
        link.read_registers(1, RegisterTable::input, 0x0000, status);
      } while (((status[0] >> in_position) & 1u) == 0);
    });
  }
  report(state, *peer.bus, before);
}

void BM_DriveRoundTrip(benchmark::State& state, bool rtu) {
  Peer peer(rtu, std::chrono::milliseconds(1));
  ModbusDrive drive("bench", peer.bus, 1, peer.map);
  drive.enable(true);
  const auto before = peer.bus->counters();
  for (auto _ : state) {
    drive.start_move(0, 100000, 1e6);
    while (drive.status().busy) std::this_thread::sleep_for(std::chrono::microseconds(20));
  }
  report(state, *peer.bus, before);
  if (drive.status().alarm) state.SkipWithError(drive.status().alarm_cause.c_str());
}

}  // namespace

BENCHMARK_CAPTURE(BM_ProtocolRoundTrip, tcp_loopback, false)->Unit(benchmark::kMicrosecond)->UseRealTime();
BENCHMARK_CAPTURE(BM_ProtocolRoundTrip, rtu_pty_115200, true)->Unit(benchmark::kMicrosecond)->UseRealTime();
BENCHMARK_CAPTURE(BM_DriveRoundTrip, tcp_loopback, false)->Unit(benchmark::kMicrosecond)->UseRealTime();
BENCHMARK_CAPTURE(BM_DriveRoundTrip, rtu_pty_115200, true)->Unit(benchmark::kMicrosecond)->UseRealTime();

BENCHMARK_MAIN();
