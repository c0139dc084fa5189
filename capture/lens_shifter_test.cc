#include "capture/lens_shifter.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <fstream>

#include "capture/lens_shifter_sim.h"
#include "core/error.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

double SecondsSince(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

LensShifterOptions OptionsFor(const LensShifterSim& sim) {
  LensShifterOptions o;
  o.port = sim.Port();
  o.reply_timeout_s = 0.3;
  o.move_timeout_s = 1.0;
  return o;
}

std::string DeviceErrorOf(const std::function<void()>& fn) {
  try {
    fn();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kDevice) << e.what();
    return e.what();
  }
  return "(no error)";
}

TEST(LensShifterTest, MovesOverPseudoTerminal) {
  LensShifterSim sim;
  LensShifterController c(OptionsFor(sim));
  EXPECT_EQ(c.id(), "mesoscan lens-shifter simulator 1");
  EXPECT_EQ(c.Position(), 0);
  EXPECT_EQ(c.MoveTo(-2048), -2048);
  EXPECT_EQ(sim.position(), -2048);
  EXPECT_EQ(c.MoveTo(1966), 1966);
  EXPECT_EQ(c.Position(), 1966);
  EXPECT_EQ(c.Home(), 0);
  EXPECT_EQ(sim.position(), 0);
  EXPECT_EQ(sim.commands(), 6);
}

TEST(LensShifterTest, ControllerErrorsAreDeviceErrors) {
  LensShifterSim sim;
  LensShifterController c(OptionsFor(sim));
  sim.InjectError("limit switch");
  EXPECT_EQ(DeviceErrorOf([&] { c.MoveTo(100); }),
            sim.Port() + ": MOVE 100: controller error: limit switch");
  sim.InjectReply("BUSY");
  EXPECT_EQ(DeviceErrorOf([&] { c.Position(); }),
            sim.Port() + ": unexpected reply \"BUSY\" to \"POS?\"");
  sim.InjectReply("OK twelve");
  EXPECT_EQ(DeviceErrorOf([&] { c.Position(); }),
            sim.Port() + ": unexpected reply \"OK twelve\" to \"POS?\", expected \"OK <steps>\"");
  sim.InjectReply("OK 7");  // the motor stalled short of the target
  EXPECT_EQ(DeviceErrorOf([&] { c.MoveTo(50); }),
            sim.Port() + ": MOVE 50: controller reports position 7 after the move");
  EXPECT_EQ(DeviceErrorOf([&] { c.Command("FLY", 0.3); }),
            sim.Port() + ": FLY: controller error: unknown command");
  // The driver recovers: the next command is answered normally.
  EXPECT_EQ(c.MoveTo(10), 10);
}

TEST(LensShifterTest, OutOfRangeRefusedBeforeSending) {
  LensShifterSim sim;
  LensShifterController c(OptionsFor(sim));
  const int before = sim.commands();
  try {
    c.MoveTo(5000);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kBadInput);
    EXPECT_EQ(std::string(e.what()), sim.Port() + ": MOVE 5000: outside range_steps [-2048, 2048]");
  }
  EXPECT_EQ(sim.commands(), before);
}

TEST(LensShifterTest, SilentControllerTimesOut) {
  LensShifterSim sim;
  LensShifterController c(OptionsFor(sim));
  sim.SetMute(true);
  const auto t0 = Clock::now();
  EXPECT_EQ(DeviceErrorOf([&] { c.Position(); }),
            sim.Port() + ": no reply to \"POS?\" within 0.3 s");
  const double elapsed = SecondsSince(t0);
  EXPECT_GE(elapsed, 0.29);
  EXPECT_LT(elapsed, 1.0);
  // A reply cut short (no newline) also times out, and says what arrived.
  sim.SetMute(false);
  sim.InjectRaw("OK 1");
  EXPECT_EQ(DeviceErrorOf([&] { c.Position(); }),
            sim.Port() + ": no reply to \"POS?\" within 0.3 s (partial: \"OK 1\")");
  EXPECT_EQ(c.Position(), 0);  // the stale bytes are flushed before the next command
  // Constructor: a silent port fails within the reply timeout.
  sim.SetMute(true);
  const auto t1 = Clock::now();
  EXPECT_EQ(DeviceErrorOf([&] { LensShifterController again(OptionsFor(sim)); }),
            sim.Port() + ": no reply to \"ID?\" within 0.3 s");
  EXPECT_LT(SecondsSince(t1), 1.0);
}

TEST(LensShifterTest, SlowMoveUsesMoveTimeout) {
  LensShifterSimOptions so;
  so.steps_per_second = 4000;  // 2048 steps: ~0.5 s, longer than the 0.3 s reply timeout
  LensShifterSim sim(so);
  LensShifterController c(OptionsFor(sim));
  const auto t0 = Clock::now();
  EXPECT_EQ(c.MoveTo(2048), 2048);
  EXPECT_GT(SecondsSince(t0), 0.4);
  // The same move with a move timeout shorter than the move itself.
  LensShifterOptions o = OptionsFor(sim);
  o.move_timeout_s = 0.2;
  LensShifterController impatient(o);
  EXPECT_EQ(DeviceErrorOf([&] { impatient.MoveTo(-2048); }),
            sim.Port() + ": no reply to \"MOVE -2048\" within 0.2 s");
}

TEST(LensShifterTest, LineDropIsDetected) {
  auto sim = std::make_unique<LensShifterSim>();
  LensShifterController c(OptionsFor(*sim));
  const std::string port = sim->Port();
  sim->Close();
  const auto t0 = Clock::now();
  const std::string err = DeviceErrorOf([&] { c.Position(); });
  EXPECT_LT(SecondsSince(t0), 1.0);
  // The hang-up is seen when sending or waiting, or the deadline passes; all name the port.
  EXPECT_TRUE(err == port + ": connection closed while sending \"POS?\"" ||
              err == port + ": connection closed while waiting for the reply to \"POS?\"" ||
              err == port + ": no reply to \"POS?\" within 0.3 s")
      << err;
}

TEST(LensShifterTest, OpenErrors) {
  LensShifterOptions o;
  o.port = "/dev/does-not-exist-mesoscan";
  EXPECT_EQ(DeviceErrorOf([&] { LensShifterController c(o); }),
            "/dev/does-not-exist-mesoscan: cannot open (No such file or directory)");
  const fs::path file =
      fs::temp_directory_path() / ("mesoscan_not_tty_" + std::to_string(getpid()));
  std::ofstream(file) << "x";
  o.port = file.string();
  EXPECT_EQ(DeviceErrorOf([&] { LensShifterController c(o); }),
            file.string() + ": not a serial port (Inappropriate ioctl for device)");
  fs::remove(file);
  o.baud = 1234;
  EXPECT_THROW(o.Check(), Error);
}

TEST(LensShifterTest, ListSerialPorts) {
  const fs::path dev = fs::temp_directory_path() / ("mesoscan_dev_" + std::to_string(getpid()));
  fs::create_directories(dev / "serial/by-id");
  for (const char* name : {"ttyUSB0", "ttyACM1", "ttyS0", "null"}) std::ofstream(dev / name);
  std::ofstream(dev / "serial/by-id/usb-FTDI_FT232R-if00-port0");
  const std::vector<std::string> ports = ListSerialPorts(dev);
  EXPECT_EQ(ports,
            (std::vector<std::string>{(dev / "serial/by-id/usb-FTDI_FT232R-if00-port0").string(),
                                      (dev / "ttyACM1").string(), (dev / "ttyUSB0").string()}));
  fs::remove_all(dev);
  EXPECT_TRUE(ListSerialPorts(dev).empty());
}

}  // namespace
}  // namespace mesoscan
