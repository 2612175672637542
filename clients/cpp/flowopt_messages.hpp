// flowopt wire messages (version 2) for C++ iceoryx2 controllers.
//
// The two payloads the flowopt daemon and its controllers exchange over
// iceoryx2 shared memory, laid out exactly as docs/MESSAGES.md says (the Rust
// `#[repr(C)]` structs of client-lib/src/messages.rs, little-endian x86-64):
// every offset and size is pinned by a static_assert below. Each payload
// names its Rust type in `IOX2_TYPE_NAME`, which iceoryx2's C++ bindings
// compare with the service's type when it is opened.
//
// Also here: the status and reason codes, the followability contract
// (`decide`: follow this message's trajectory, bring the robots to rest, or
// ignore an answer from before the controller started) and the evaluation
// of a plan at a time (`sample_robot`: Bernstein polynomials and their first
// two derivatives). Header-only, C++17, no dependencies; how to open the
// services is in clients/cpp/README.md.

#ifndef FLOWOPT_MESSAGES_HPP
#define FLOWOPT_MESSAGES_HPP

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <string_view>
#include <type_traits>
#include <utility>

namespace flowopt {

/// Layout version written into every message.
constexpr std::uint32_t WIRE_VERSION = 2;
/// Robots per team a message can carry.
constexpr std::size_t MAX_ROBOTS = 256;
/// Obstacles a snapshot can carry.
constexpr std::size_t MAX_OBSTACLES = 16;
/// Bernstein coefficients per robot and axis (degree at most 15).
constexpr std::size_t MAX_COEFFS = 16;
/// Bytes of the team name (UTF-8, NUL-padded).
constexpr std::size_t TEAM_NAME_LEN = 32;
/// `reason_index` when the reason points at no robot or obstacle.
constexpr std::uint32_t NO_INDEX = 0xFFFFFFFFu;

/// What a plan message tells the controllers to follow (`status`).
enum class PlanStatus : std::uint32_t { NoPlan = 0, Ok = 1, Held = 2, Stopping = 3 };

/// Why a plan message is not a new plan (`reason`).
enum class Reason : std::uint32_t {
    None = 0,
    Version = 1,
    Team = 2,
    Dimension = 3,
    RobotCount = 4,
    ObstacleCount = 5,
    NonFinite = 6,
    NonPositiveSize = 7,
    StartsOverlap = 8,
    GoalsOverlap = 9,
    StartInObstacle = 10,
    GoalInObstacle = 11,
    StartOutsideWorkspace = 12,
    GoalOutsideWorkspace = 13,
    StaleState = 14,
    Solver = 15,
    Clock = 16,
    Sequence = 17,
    Implausible = 18,
    DeadlineMissed = 19,
    NotVerified = 20,
    NotFollowing = 21,
    Limits = 22,
    WorldChanged = 23,
    Recovering = 24,
    CannotBrake = 25,
    CannotAvoid = 26,
};

/// Whether `reason` rejects the answered snapshot: its task was not planned
/// (for 1-7 and 16-18 it changed nothing; for 8-13, 25 and 26 its robots and obstacles
/// are still the world the daemon checks every followable answer against).
constexpr bool is_rejection(std::uint32_t reason) {
    return (reason >= 1 && reason <= 13) || (reason >= 16 && reason <= 18) || reason == 25 || reason == 26;
}

/// Whether a message with wire status `status` carries a verified trajectory.
constexpr bool followable(std::uint32_t status) {
    return status >= static_cast<std::uint32_t>(PlanStatus::Ok) &&
           status <= static_cast<std::uint32_t>(PlanStatus::Stopping);
}

/// One robot's measured position and velocity, and its goal.
struct RobotState {
    static constexpr const char* IOX2_TYPE_NAME = "flowopt::RobotState";
    double position[3];  ///< m
    double velocity[3];  ///< m/s
    double goal[3];      ///< m, reached at rest at the end of the horizon
};

/// A spheroid moving at constant velocity from `position` at the snapshot's time.
struct ObstacleState {
    static constexpr const char* IOX2_TYPE_NAME = "flowopt::ObstacleState";
    double position[3];  ///< m
    double velocity[3];  ///< m/s
    double radius;       ///< m, in the plane
    double half_height;  ///< m, along z (3D)
};

/// Controller to daemon: the measured state of a whole team.
struct StateSnapshot {
    static constexpr const char* IOX2_TYPE_NAME = "flowopt::StateSnapshot";
    std::uint32_t version;               ///< WIRE_VERSION
    std::uint32_t dim;                   ///< 2 or 3
    std::uint8_t team[TEAM_NAME_LEN];    ///< team name, NUL-padded
    std::uint64_t sequence;              ///< increases per snapshot of one publisher
    std::uint64_t timestamp_ns;          ///< CLOCK_MONOTONIC when measured
    std::uint32_t robots;                ///< robots in use (the team's count)
    std::uint32_t obstacles;             ///< obstacles in use
    ObstacleState obstacle[MAX_OBSTACLES];
    RobotState robot[MAX_ROBOTS];        ///< last: a message uses a prefix
};

/// Microseconds per planning stage.
struct StageTimings {
    static constexpr const char* IOX2_TYPE_NAME = "flowopt::StageTimings";
    std::uint32_t queue_us, validate_us, warm_start_us, sample_us, rank_us, init_us, filter_us, optimise_us,
        select_us, total_us;
};

/// Daemon to controllers: the answer to one snapshot.
struct JointTrajectory {
    static constexpr const char* IOX2_TYPE_NAME = "flowopt::JointTrajectory";
    std::uint32_t version;             ///< WIRE_VERSION
    std::uint32_t status;              ///< PlanStatus: what to follow
    std::uint32_t reason;              ///< Reason: why this is not a new plan
    std::uint32_t reason_index;        ///< robot (or 256 + obstacle) at fault; NO_INDEX none
    std::uint8_t team[TEAM_NAME_LEN];  ///< team name, NUL-padded
    std::uint32_t dim;                 ///< 2 or 3
    std::uint32_t robots;              ///< robots in the plan
    std::uint32_t degree;              ///< Bernstein degree; degree + 1 coefficients used
    std::uint32_t iterations;          ///< solver iterations spent on this answer
    std::uint64_t answers_sequence;    ///< the snapshot this message answers
    std::uint64_t state_timestamp_ns;  ///< its timestamp
    std::uint64_t plan_sequence;       ///< the snapshot the carried plan was made from
    std::uint64_t plan_origin_ns;      ///< the carried plan's t = 0 (CLOCK_MONOTONIC)
    std::uint64_t received_ns;         ///< when the daemon took the answered snapshot
    std::uint64_t published_ns;        ///< when the daemon published this
    double horizon;                    ///< T (s): goals reached at rest at origin + T
    double primal_residual;            ///< m
    double smoothness;                 ///< m^2/s^4
    double max_speed;                  ///< m/s
    double max_acceleration;           ///< m/s^2
    std::uint32_t warm_started;        ///< 1 if warm-started from the previous plan
    std::uint32_t candidates;          ///< candidates refined
    StageTimings timings;
    double coeffs[MAX_ROBOTS][3][MAX_COEFFS];  ///< [robot][axis][coef]
};

// The layout of docs/MESSAGES.md, pinned.
static_assert(sizeof(double) == 8 && alignof(std::uint64_t) == 8, "an LP64 target (x86-64, aarch64)");
static_assert(std::is_standard_layout_v<StateSnapshot> && std::is_trivially_copyable_v<StateSnapshot>);
static_assert(std::is_standard_layout_v<JointTrajectory> && std::is_trivially_copyable_v<JointTrajectory>);
static_assert(sizeof(RobotState) == 72 && offsetof(RobotState, position) == 0 &&
              offsetof(RobotState, velocity) == 24 && offsetof(RobotState, goal) == 48);
static_assert(sizeof(ObstacleState) == 64 && offsetof(ObstacleState, position) == 0 &&
              offsetof(ObstacleState, velocity) == 24 && offsetof(ObstacleState, radius) == 48 &&
              offsetof(ObstacleState, half_height) == 56);
static_assert(offsetof(StateSnapshot, version) == 0);
static_assert(offsetof(StateSnapshot, dim) == 4);
static_assert(offsetof(StateSnapshot, team) == 8);
static_assert(offsetof(StateSnapshot, sequence) == 40);
static_assert(offsetof(StateSnapshot, timestamp_ns) == 48);
static_assert(offsetof(StateSnapshot, robots) == 56);
static_assert(offsetof(StateSnapshot, obstacles) == 60);
static_assert(offsetof(StateSnapshot, obstacle) == 64);
static_assert(offsetof(StateSnapshot, robot) == 1088);
static_assert(sizeof(StateSnapshot) == 19520 && alignof(StateSnapshot) == 8);
static_assert(sizeof(StageTimings) == 40 && offsetof(StageTimings, total_us) == 36);
static_assert(offsetof(JointTrajectory, version) == 0);
static_assert(offsetof(JointTrajectory, status) == 4);
static_assert(offsetof(JointTrajectory, reason) == 8);
static_assert(offsetof(JointTrajectory, reason_index) == 12);
static_assert(offsetof(JointTrajectory, team) == 16);
static_assert(offsetof(JointTrajectory, dim) == 48);
static_assert(offsetof(JointTrajectory, robots) == 52);
static_assert(offsetof(JointTrajectory, degree) == 56);
static_assert(offsetof(JointTrajectory, iterations) == 60);
static_assert(offsetof(JointTrajectory, answers_sequence) == 64);
static_assert(offsetof(JointTrajectory, state_timestamp_ns) == 72);
static_assert(offsetof(JointTrajectory, plan_sequence) == 80);
static_assert(offsetof(JointTrajectory, plan_origin_ns) == 88);
static_assert(offsetof(JointTrajectory, received_ns) == 96);
static_assert(offsetof(JointTrajectory, published_ns) == 104);
static_assert(offsetof(JointTrajectory, horizon) == 112);
static_assert(offsetof(JointTrajectory, primal_residual) == 120);
static_assert(offsetof(JointTrajectory, smoothness) == 128);
static_assert(offsetof(JointTrajectory, max_speed) == 136);
static_assert(offsetof(JointTrajectory, max_acceleration) == 144);
static_assert(offsetof(JointTrajectory, warm_started) == 152);
static_assert(offsetof(JointTrajectory, candidates) == 156);
static_assert(offsetof(JointTrajectory, timings) == 160);
static_assert(offsetof(JointTrajectory, coeffs) == 200);
static_assert(sizeof(JointTrajectory) == 98504 && alignof(JointTrajectory) == 8);

/// Writes `name` NUL-padded into a message's `team`; false (and nothing
/// written) unless it is 1-32 bytes without '/' or NUL.
inline bool set_team(std::uint8_t (&team)[TEAM_NAME_LEN], std::string_view name) {
    if (name.empty() || name.size() > TEAM_NAME_LEN || name.find('/') != std::string_view::npos ||
        name.find('\0') != std::string_view::npos) {
        return false;
    }
    std::memset(team, 0, TEAM_NAME_LEN);
    std::memcpy(team, name.data(), name.size());
    return true;
}

/// The team name of a message (up to the first NUL).
inline std::string_view team_name(const std::uint8_t (&team)[TEAM_NAME_LEN]) {
    const auto* begin = reinterpret_cast<const char*>(team);
    return {begin, static_cast<std::size_t>(std::find(begin, begin + TEAM_NAME_LEN, '\0') - begin)};
}

/// Whether a followable message has a shape a plan can have: dim 2 or 3,
/// 1-256 robots, degree 1-15, a positive finite horizon.
inline bool has_plan(const JointTrajectory& msg) {
    return followable(msg.status) && (msg.dim == 2 || msg.dim == 3) && msg.robots >= 1 &&
           msg.robots <= MAX_ROBOTS && msg.degree >= 1 && msg.degree < MAX_COEFFS && std::isfinite(msg.horizon) &&
           msg.horizon > 0.0;
}

/// The snapshots a controller published most recently, by sequence and
/// timestamp (the last `REMEMBERED`): `record` each one as it is sent, and
/// `decide` recognises the answers to them.
class Sent {
public:
    /// Snapshots remembered (at 1 kHz, the last second).
    static constexpr std::size_t REMEMBERED = 1024;

    /// Remembers a published snapshot (forgetting the oldest beyond `REMEMBERED`).
    void record(std::uint64_t sequence, std::uint64_t timestamp_ns) {
        ring_[next_ % REMEMBERED] = {sequence, timestamp_ns};
        ++next_;
    }

    /// Whether the snapshot of `sequence` stamped `timestamp_ns` is remembered.
    bool contains(std::uint64_t sequence, std::uint64_t timestamp_ns) const {
        const std::size_t n = next_ < REMEMBERED ? next_ : REMEMBERED;
        for (std::size_t i = 0; i < n; ++i) {
            if (ring_[i].first == sequence && ring_[i].second == timestamp_ns) {
                return true;
            }
        }
        return false;
    }

private:
    std::array<std::pair<std::uint64_t, std::uint64_t>, REMEMBERED> ring_{};
    std::size_t next_ = 0;
};

/// What a controller does with the newest plan message it takes (the
/// followability contract, docs/MESSAGES.md).
enum class Decision {
    /// Follow this message's trajectory from now on (evaluate it against its
    /// `plan_origin_ns`); it replaces whatever was followed.
    Follow,
    /// Nothing to follow (NoPlan, or a status or shape no daemon writes):
    /// bring the robots to rest by your own means.
    Rest,
    /// An answer to another snapshot than this controller's own (another
    /// process's, or the last message a service keeps for late joiners):
    /// change nothing.
    Ignore,
};

/// The contract for the newest message `msg`, for a controller that
/// published the snapshots in `sent`.
inline Decision decide(const JointTrajectory& msg, const Sent& sent) {
    if (!sent.contains(msg.answers_sequence, msg.state_timestamp_ns)) {
        return Decision::Ignore;
    }
    return has_plan(msg) ? Decision::Follow : Decision::Rest;
}

/// Seconds from the carried plan's origin to `now_ns` (negative before it).
inline double elapsed_s(const JointTrajectory& msg, std::uint64_t now_ns) {
    return static_cast<double>(static_cast<std::int64_t>(now_ns - msg.plan_origin_ns)) * 1e-9;
}

/// `d^order/dtau^order` of the `degree + 1` Bernstein polynomials of
/// `degree` at `tau`, into `row[0..=degree]`:
/// `N!/(N-r)! sum_j (-1)^(r-j) C(r,j) B_{i-j,N-r}(tau)`.
inline void bernstein_row(unsigned degree, unsigned order, double tau, double* row) {
    std::fill(row, row + degree + 1, 0.0);
    if (order > degree) {
        return;
    }
    auto binomial = [](unsigned n, unsigned k) {
        double c = 1.0;
        for (unsigned i = 0; i < k; ++i) {
            c = c * static_cast<double>(n - i) / static_cast<double>(i + 1);
        }
        return c;
    };
    const unsigned low = degree - order;
    double lower[MAX_COEFFS];
    for (unsigned i = 0; i <= low; ++i) {
        lower[i] = binomial(low, i) * std::pow(tau, i) * std::pow(1.0 - tau, low - i);
    }
    double falling = 1.0;
    for (unsigned i = 0; i < order; ++i) {
        falling *= static_cast<double>(degree - i);
    }
    for (unsigned i = 0; i <= degree; ++i) {
        double sum = 0.0;
        for (unsigned j = 0; j <= order; ++j) {
            if (i >= j && i - j <= low) {
                sum += ((order - j) % 2 == 0 ? 1.0 : -1.0) * binomial(order, j) * lower[i - j];
            }
        }
        row[i] = falling * sum;
    }
}

/// Position (m), velocity (m/s) and acceleration (m/s^2) of one robot; in 2D
/// the third entries are 0.
struct Kinematics {
    double position[3];
    double velocity[3];
    double acceleration[3];
};

/// Robot `robot`'s kinematics `t` seconds after `msg.plan_origin_ns`
/// (clamped to [0, horizon]: before the plan its start, after it the goal at
/// rest). False (and `out` zeroed) if `msg` carries no plan (`has_plan`) or
/// has no such robot.
inline bool sample_robot(const JointTrajectory& msg, std::uint32_t robot, double t, Kinematics& out) {
    out = Kinematics{};
    if (!has_plan(msg) || robot >= msg.robots) {
        return false;
    }
    const double tau = std::clamp(t / msg.horizon, 0.0, 1.0);
    const double scale[3] = {1.0, 1.0 / msg.horizon, 1.0 / (msg.horizon * msg.horizon)};
    double* series[3] = {out.position, out.velocity, out.acceleration};
    double row[MAX_COEFFS];
    for (unsigned order = 0; order < 3; ++order) {
        bernstein_row(msg.degree, order, tau, row);
        for (unsigned a = 0; a < msg.dim; ++a) {
            double value = 0.0;
            for (unsigned c = 0; c <= msg.degree; ++c) {
                value += row[c] * msg.coeffs[robot][a][c];
            }
            series[order][a] = value * scale[order];
        }
    }
    return true;
}

}  // namespace flowopt

#endif  // FLOWOPT_MESSAGES_HPP
