#pragma once
// A simulated lens-shifter controller: answers the line protocol of capture/lens_shifter.h on the
// master side of a pseudo-terminal (posix_openpt) from its own thread. Open Port() (the slave
// device, e.g. /dev/pts/7) with LensShifterController exactly as a real serial port. Used by the
// tests and by `capture --rehearse` (app/rehearsal.h) rehearsals without hardware.

#include <array>
#include <atomic>
#include <mutex>
#include <string>
#include <thread>

namespace mesoscan {

struct LensShifterSimOptions {
  std::array<int, 2> range_steps{-2048, 2048};  // MOVE outside answers "ERR out of range"
  double steps_per_second = 1e6;  // > 0; a move of n steps delays its reply by n / this
  std::string id = "mesoscan lens-shifter simulator 1";  // the ID? reply
};

class LensShifterSim {
 public:
  explicit LensShifterSim(const LensShifterSimOptions& options = {});
  ~LensShifterSim();  // stops the thread and closes the pty
  LensShifterSim(const LensShifterSim&) = delete;
  LensShifterSim& operator=(const LensShifterSim&) = delete;

  const std::string& Port() const { return port_; }
  int position() const { return position_; }
  int commands() const { return commands_; }  // command lines received

  // Fault injection for tests.
  void SetMute(bool mute) { mute_ = mute; }      // read commands but never answer
  void InjectError(const std::string& message);  // the next command gets "ERR <message>"
  void InjectReply(const std::string& line) { InjectRaw(line + "\n"); }  // instead of the answer
  void InjectRaw(const std::string& bytes);  // exactly these bytes (e.g. a line cut short)
  // Closes the pty master: the controller then sees the line drop.
  void Close();

 private:
  void Run();
  std::string Answer(const std::string& line);  // the reply bytes, newline included

  LensShifterSimOptions options_;
  int master_ = -1;
  int slave_ = -1;  // kept open so the master never sees a hang-up between client sessions
  std::string port_;
  std::atomic<int> position_{0};
  std::atomic<int> commands_{0};
  std::atomic<bool> mute_{false};
  std::atomic<bool> stop_{false};
  std::mutex inject_mutex_;
  std::string inject_;  // raw reply for the next command, if not empty
  std::thread thread_;
};

}  // namespace mesoscan
