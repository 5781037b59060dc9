#include "markerd/rig/modbus_bus.hpp"

#include <fmt/format.h>
#include <modbus.h>
#include <poll.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <exception>
#include <map>
#include <mutex>
#include <stdexcept>
#include <string_view>
#include <thread>
#include <utility>

namespace markerd::rig {

std::string ModbusBusSettings::describe() const {
  if (transport == ModbusTransport::tcp) return fmt::format("{} ({}:{})", name, host, port);
  return fmt::format("{} ({}, {} {}{}{})", name, device, baud, data_bits, parity, stop_bits);
}

ModbusBusSettings parse_modbus_bus(const ConfigTable& t) {
  ModbusBusSettings s;
  const auto& path = t.key_path();
  s.name = path.substr(path.rfind('.') + 1);
  const auto type = t.required<std::string>("type");
  if (type == "rtu") {
    s.transport = ModbusTransport::rtu;
    t.allow_only({"type", "device", "baud", "parity", "data_bits", "stop_bits", "response_timeout_ms",
                  "byte_timeout_ms", "retries", "poll_ms"});
    s.device = t.required<std::string>("device");
    // libmodbus refuses an empty one only when markerd starts.
    if (s.device.empty()) t.fail("device", "must name the serial device (a path such as /dev/ttyUSB0)");
    s.baud = static_cast<int>(t.optional<std::int64_t>("baud", s.baud, {1200, 921600, "baud"}));
    // libmodbus quietly falls back to 9600 baud for a rate termios lacks.
    constexpr std::array kBauds{1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600};
    if (std::find(kBauds.begin(), kBauds.end(), s.baud) == kBauds.end()) {
      t.fail("baud", fmt::format("must be a standard rate (1200 to 921600), got {}", s.baud));
    }
    const auto parity = t.optional<std::string>("parity", "even");
    if (parity == "none")
      s.parity = 'N';
    else if (parity == "even")
      s.parity = 'E';
    else if (parity == "odd")
      s.parity = 'O';
    else
      t.fail("parity", fmt::format("must be \"none\", \"even\" or \"odd\", got \"{}\"", parity));
    s.data_bits = static_cast<int>(t.optional<std::int64_t>("data_bits", s.data_bits, {7, 8}));
    s.stop_bits = static_cast<int>(t.optional<std::int64_t>("stop_bits", s.stop_bits, {1, 2}));
    if (s.stop_bits != 1 && s.stop_bits != 2) t.fail("stop_bits", fmt::format("must be 1 or 2, got {}", s.stop_bits));
  } else if (type == "tcp") {
    s.transport = ModbusTransport::tcp;
    t.allow_only({"type", "host", "port", "response_timeout_ms", "byte_timeout_ms", "retries", "poll_ms"});
    s.host = t.required<std::string>("host");
    if (s.host.empty()) t.fail("host", "must name the server (a host name or an address)");
    s.port = static_cast<int>(t.optional<std::int64_t>("port", s.port, {1, 65535}));
  } else {
    t.fail("type", fmt::format("must be \"rtu\" or \"tcp\", got \"{}\"", type));
  }
  // Every request waits at most (retries + 1) response timeouts: these bound
  // how long a command or a stop can wait for a drive that does not answer.
  const auto ms = [&](std::string_view key, std::chrono::milliseconds fallback, std::int64_t min, std::int64_t max) {
    return std::chrono::milliseconds(t.optional<std::int64_t>(key, fallback.count(), {min, max, "ms"}));
  };
  s.response_timeout = ms("response_timeout_ms", s.response_timeout, 1, 10000);
  s.byte_timeout = ms("byte_timeout_ms", s.byte_timeout, 0, 10000);
  s.poll_period = ms("poll_ms", s.poll_period, 1, 10000);
  s.retries = static_cast<int>(t.optional<std::int64_t>("retries", s.retries, {0, 10}));
  return s;
}

namespace {

void set_timeout(modbus_t* ctx, std::chrono::milliseconds timeout,
                 int (*setter)(modbus_t*, std::uint32_t, std::uint32_t)) {
  const auto us = std::chrono::duration_cast<std::chrono::microseconds>(timeout).count();
  setter(ctx, static_cast<std::uint32_t>(us / 1000000), static_cast<std::uint32_t>(us % 1000000));
}

// Errors after which the connection (or the serial device) is no use any more.
bool is_link_error(int err) {
  switch (err) {
    case ECONNRESET:
    case ECONNREFUSED:
    case ECONNABORTED:
    case EPIPE:
    case ENOTCONN:
    case EBADF:
    case ENETUNREACH:
    case EHOSTUNREACH:
    case EIO:
    case ENXIO:
    case ENODEV: return true;
    default: return false;
  }
}

}  // namespace

struct ModbusBus::Impl final : ModbusLink {
  struct Job {
    const Work* work = nullptr;
    std::exception_ptr error;
    bool started = false;  // taken from the queue by the bus thread
    bool done = false;
  };
  struct Slot {
    Client client;
    std::atomic<bool> urgent{false};
    int running = 0;  // callbacks of this client in progress (guarded by mutex)
  };

  ModbusBusSettings settings;
  std::string description_;
  modbus_t* ctx = nullptr;
  bool connected = false;  // bus thread only (and the constructor before it starts)
  bool in_urgent = false;  // bus thread only

  mutable std::mutex mutex;
  std::condition_variable wake;      // the bus thread waits on it
  std::condition_variable finished;  // callers of execute() and detach() wait on it
  std::deque<Job*> queue;
  std::map<ClientId, std::unique_ptr<Slot>> clients;
  ClientId next_client = 1;
  bool stopping = false;
  std::atomic<bool> urgent_pending{false};

  std::atomic<std::uint64_t> n_requests{0}, n_retries{0}, n_failures{0}, n_reconnects{0};
  std::jthread thread;

  explicit Impl(ModbusBusSettings s) : settings(std::move(s)), description_(settings.describe()) {
    if (settings.transport == ModbusTransport::rtu) {
      ctx = modbus_new_rtu(settings.device.c_str(), settings.baud, settings.parity, settings.data_bits,
                           settings.stop_bits);
    } else {
      ctx = modbus_new_tcp_pi(settings.host.c_str(), std::to_string(settings.port).c_str());
    }
    if (ctx == nullptr) {
      throw std::invalid_argument(
          fmt::format("modbus bus {}: libmodbus refuses these settings: {}", description_, modbus_strerror(errno)));
    }
    set_timeout(ctx, settings.response_timeout, modbus_set_response_timeout);
    set_timeout(ctx, settings.byte_timeout, modbus_set_byte_timeout);
    // Recovery is ours: libmodbus's own would sleep a full response timeout.
    modbus_set_error_recovery(ctx, MODBUS_ERROR_RECOVERY_NONE);
    std::string cause;
    if (!connect(cause)) {
      modbus_free(ctx);
      throw DriveError(fmt::format("modbus bus {}: {}", description_, cause));
    }
    thread = std::jthread([this] { run(); });
  }

  ~Impl() override {
    {
      std::lock_guard lock(mutex);
      stopping = true;
    }
    wake.notify_all();
    if (thread.joinable()) thread.join();
    if (connected) modbus_close(ctx);
    modbus_free(ctx);
  }

  [[nodiscard]] const std::string& description() const override { return description_; }

  // The longest a request may wait in the queue (mutex held): the bus busy
  // with every job ahead and a poll of every client, several requests each,
  // every request with all its attempts timing out. Far beyond what a
  // working bus needs; a request still queued after it means the bus thread
  // is stuck, and the caller gets an error instead of a wait without end.
  [[nodiscard]] std::chrono::milliseconds queue_wait_limit() const {
    const auto per_request = (settings.retries + 1) * (2 * settings.response_timeout + std::chrono::milliseconds(200));
    const auto requests = 4 * static_cast<std::int64_t>(queue.size() + clients.size()) + 4;
    return std::chrono::duration_cast<std::chrono::milliseconds>(per_request * requests) + settings.poll_period;
  }

  bool connect(std::string& cause) {
    if (modbus_connect(ctx) == 0) {
      connected = true;
      return true;
    }
    const int err = errno;
    if (settings.transport == ModbusTransport::rtu) {
      cause = fmt::format("cannot open {}: {}", settings.device, modbus_strerror(err));
    } else {
      cause = fmt::format("cannot connect to {}:{}: {}", settings.host, settings.port, modbus_strerror(err));
    }
    return false;
  }

  void disconnect() {
    modbus_close(ctx);
    connected = false;
  }

  // After a timeout or a bad frame, a late or partial reply may still be on
  // its way: wait until the line has been quiet for a byte timeout (at most
  // one response timeout) and throw away what came, so that the next
  // attempt's reply is not confused with this one's.
  void discard_pending_input() {
    modbus_flush(ctx);
    const int fd = modbus_get_socket(ctx);
    if (fd < 0) return;
    const auto quiet = std::max(settings.byte_timeout, std::chrono::milliseconds(5));
    const auto deadline = std::chrono::steady_clock::now() + settings.response_timeout;
    std::array<std::uint8_t, 256> sink{};
    while (std::chrono::steady_clock::now() < deadline) {
      pollfd p{fd, POLLIN, 0};
      if (::poll(&p, 1, static_cast<int>(quiet.count())) <= 0) return;
      if (::read(fd, sink.data(), sink.size()) <= 0) return;
    }
  }

  std::string describe_error(int err) const {
    if (err == ETIMEDOUT) return fmt::format("no reply within {} ms", settings.response_timeout.count());
    if (err == EMBBADCRC) return "reply with a bad CRC";
    if (err == EMBBADSLAVE) return "reply from another unit";
    if (err == EMBBADDATA) return "reply that does not match the request";
    if (err >= EMBXILFUN && err <= EMBXGTAR) {
      return fmt::format("exception reply 0x{:02X} ({})", err - MODBUS_ENOBASE, modbus_strerror(err));
    }
    return modbus_strerror(err);
  }

  // Runs one Modbus request with the bus's retries. `request` returns
  // libmodbus's result (-1 with errno on failure).
  template <class Request>
  void perform(int unit, int attempts, const std::function<std::string()>& what, Request&& request) {
    const int total = attempts > 0 ? attempts : settings.retries + 1;
    std::string cause;
    for (int attempt = 1; attempt <= total; ++attempt) {
      if (attempt > 1) n_retries.fetch_add(1, std::memory_order_relaxed);
      if (!in_urgent && urgent_pending.load(std::memory_order_acquire)) run_urgent();
      if (!connected) {
        if (!connect(cause)) {
          // Refused at once: do not spin through the attempts.
          std::this_thread::sleep_for(std::min(settings.response_timeout, std::chrono::milliseconds(200)));
          continue;
        }
        n_reconnects.fetch_add(1, std::memory_order_relaxed);
      }
      modbus_set_slave(ctx, unit);
      n_requests.fetch_add(1, std::memory_order_relaxed);
      if (request() >= 0) return;
      const int err = errno;
      cause = describe_error(err);
      if (is_link_error(err)) {
        disconnect();
      } else {
        discard_pending_input();
      }
    }
    n_failures.fetch_add(1, std::memory_order_relaxed);
    throw DriveError(fmt::format("modbus bus {}, unit {}: {}: {} ({} attempt{})", description_, unit, what(), cause,
                                 total, total == 1 ? "" : "s"));
  }

  void read_registers(int unit, RegisterTable table, std::uint16_t address, std::span<std::uint16_t> out,
                      int attempts) override {
    const int n = static_cast<int>(out.size());
    const auto what = [&] { return fmt::format("read {} {}s at 0x{:04X}", n, to_string(table), address); };
    if (table == RegisterTable::holding) {
      perform(unit, attempts, what, [&] { return modbus_read_registers(ctx, address, n, out.data()); });
    } else if (table == RegisterTable::input) {
      perform(unit, attempts, what, [&] { return modbus_read_input_registers(ctx, address, n, out.data()); });
    } else {
      throw std::logic_error("read_registers on a bit table");
    }
  }

  void read_bits(int unit, RegisterTable table, std::uint16_t address, std::span<std::uint8_t> out,
                 int attempts) override {
    const int n = static_cast<int>(out.size());
    const auto what = [&] { return fmt::format("read {} {}s at 0x{:04X}", n, to_string(table), address); };
    if (table == RegisterTable::coil) {
      perform(unit, attempts, what, [&] { return modbus_read_bits(ctx, address, n, out.data()); });
    } else if (table == RegisterTable::discrete_input) {
      perform(unit, attempts, what, [&] { return modbus_read_input_bits(ctx, address, n, out.data()); });
    } else {
      throw std::logic_error("read_bits on a register table");
    }
  }

  void write_registers(int unit, std::uint16_t address, std::span<const std::uint16_t> values, bool fc16_for_single,
                       int attempts) override {
    const int n = static_cast<int>(values.size());
    if (n == 1 && !fc16_for_single) {
      perform(
          unit, attempts, [&] { return fmt::format("write holding register 0x{:04X} = {}", address, values[0]); },
          [&] { return modbus_write_register(ctx, address, values[0]); });
      return;
    }
    perform(
        unit, attempts, [&] { return fmt::format("write {} holding registers at 0x{:04X}", n, address); },
        [&] { return modbus_write_registers(ctx, address, n, values.data()); });
  }

  void write_coil(int unit, std::uint16_t address, bool on, int attempts) override {
    perform(
        unit, attempts, [&] { return fmt::format("write coil 0x{:04X} = {}", address, on ? 1 : 0); },
        [&] { return modbus_write_bit(ctx, address, on ? 1 : 0); });
  }

  // Runs one callback of a client with the client marked as running, so that
  // detach() can wait for it.
  void run_client(Slot& slot, const Work& work) {
    try {
      work(*this);
    } catch (...) {
      // Callbacks report their own failures; one that escapes must not take
      // the bus thread (and every other drive on the bus) down.
    }
    std::lock_guard lock(mutex);
    --slot.running;
    finished.notify_all();
  }

  void run_urgent() {
    in_urgent = true;
    urgent_pending.store(false, std::memory_order_release);
    for (;;) {
      Slot* slot = nullptr;
      {
        std::lock_guard lock(mutex);
        for (auto& [id, s] : clients) {
          if (s->urgent.exchange(false)) {
            slot = s.get();
            ++slot->running;
            break;
          }
        }
      }
      if (slot == nullptr) break;
      run_client(*slot, slot->client.urgent);
    }
    in_urgent = false;
  }

  void poll_clients() {
    std::vector<ClientId> ids;
    {
      std::lock_guard lock(mutex);
      for (const auto& [id, slot] : clients) ids.push_back(id);
    }
    for (const ClientId id : ids) {
      if (urgent_pending.load(std::memory_order_acquire)) run_urgent();
      Slot* slot = nullptr;
      {
        std::lock_guard lock(mutex);
        const auto it = clients.find(id);
        if (it == clients.end() || stopping) continue;
        slot = it->second.get();
        ++slot->running;
      }
      run_client(*slot, slot->client.poll);
    }
  }

  void run() {
    auto next_poll = std::chrono::steady_clock::now();
    std::unique_lock lock(mutex);
    while (!stopping) {
      if (urgent_pending.load(std::memory_order_acquire)) {
        lock.unlock();
        run_urgent();
        lock.lock();
        continue;
      }
      if (!queue.empty()) {
        Job* job = queue.front();
        queue.pop_front();
        job->started = true;
        lock.unlock();
        try {
          (*job->work)(*this);
        } catch (...) {
          job->error = std::current_exception();
        }
        lock.lock();
        job->done = true;
        finished.notify_all();
        continue;
      }
      const auto now = std::chrono::steady_clock::now();
      if (now >= next_poll) {
        lock.unlock();
        poll_clients();
        lock.lock();
        // A slow cycle (timeouts) starts the next one a full period later
        // rather than back to back, so commands still get their turn.
        next_poll = std::max(next_poll + settings.poll_period, std::chrono::steady_clock::now());
        continue;
      }
      wake.wait_until(lock, next_poll);
    }
    for (Job* job : queue) {
      job->error = std::make_exception_ptr(DriveError(fmt::format("modbus bus {}: shut down", description_)));
      job->done = true;
    }
    queue.clear();
    finished.notify_all();
  }
};

ModbusBus::ModbusBus(ModbusBusSettings settings) : impl_(std::make_unique<Impl>(std::move(settings))) {}

ModbusBus::~ModbusBus() = default;

const ModbusBusSettings& ModbusBus::settings() const { return impl_->settings; }

const std::string& ModbusBus::description() const { return impl_->description_; }

void ModbusBus::execute(const Work& work) {
  if (std::this_thread::get_id() == impl_->thread.get_id()) {
    work(*impl_);
    return;
  }
  Impl::Job job{&work, nullptr, false, false};
  {
    std::unique_lock lock(impl_->mutex);
    if (impl_->stopping) throw DriveError(fmt::format("modbus bus {}: shut down", impl_->description_));
    const auto limit = impl_->queue_wait_limit();
    impl_->queue.push_back(&job);
    impl_->wake.notify_all();
    if (!impl_->finished.wait_for(lock, limit, [&] { return job.started || job.done; })) {
      std::erase(impl_->queue, &job);
      throw DriveError(
          fmt::format("modbus bus {}: the request waited {} ms for the bus without being sent (the bus "
                      "thread is stuck)",
                      impl_->description_, limit.count()));
    }
    // Started: its requests end within the bus's timeouts and retries.
    impl_->finished.wait(lock, [&] { return job.done; });
  }
  if (job.error) std::rethrow_exception(job.error);
}

ModbusBus::ClientId ModbusBus::attach(Client client) {
  auto slot = std::make_unique<Impl::Slot>();
  slot->client = std::move(client);
  std::lock_guard lock(impl_->mutex);
  const ClientId id = impl_->next_client++;
  impl_->clients.emplace(id, std::move(slot));
  return id;
}

void ModbusBus::detach(ClientId id) {
  std::unique_lock lock(impl_->mutex);
  const auto it = impl_->clients.find(id);
  if (it == impl_->clients.end()) return;
  Impl::Slot* slot = it->second.get();
  if (std::this_thread::get_id() != impl_->thread.get_id()) {
    impl_->finished.wait(lock, [&] { return slot->running == 0; });
  }
  impl_->clients.erase(id);
}

void ModbusBus::request_urgent(ClientId id) noexcept {
  try {
    {
      std::lock_guard lock(impl_->mutex);
      const auto it = impl_->clients.find(id);
      if (it == impl_->clients.end()) return;
      it->second->urgent.store(true);
      impl_->urgent_pending.store(true, std::memory_order_release);
    }
    impl_->wake.notify_all();
  } catch (...) {
    // std::mutex::lock throws only on a broken system (EDEADLK, EINVAL); the
    // e-stop caller cannot handle it either, and must not be thrown at.
  }
}

ModbusBus::Counters ModbusBus::counters() const {
  return Counters{impl_->n_requests.load(), impl_->n_retries.load(), impl_->n_failures.load(),
                  impl_->n_reconnects.load()};
}

}  // namespace markerd::rig
