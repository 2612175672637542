// Checks of flowopt_messages.hpp (its static_asserts hold by compiling it).
//
//   g++ -std=c++17 -O2 -Wall -Wextra -Werror -o check clients/cpp/check.cpp
//   ./check                      # evaluates known plans, checks the contract
//   ./check plan.bin 0 1.5 5     # prints a plan message's kinematics as JSON
//   ./check - 0 1.5 5 < plan.bin
//
// The second form prints the same samples as the Rust client's
// `evaluate_plan` example; the Python tests compare the two
// (FLOWOPT_CPP_CHECK=path/to/check).

#include "flowopt_messages.hpp"

#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <iterator>
#include <memory>
#include <string>
#include <vector>

namespace {

int failures = 0;
int checks = 0;

void expect(bool ok, const std::string& what) {
    ++checks;
    if (!ok) {
        ++failures;
        std::cerr << "FAILED: " << what << "\n";
    }
}

void expect_near(double actual, double expected, const std::string& what) {
    expect(std::fabs(actual - expected) <= 1e-12 * (1.0 + std::fabs(expected)),
           what + ": " + std::to_string(actual) + " != " + std::to_string(expected));
}

double binomial(unsigned n, unsigned k) {
    return k > n ? 0.0 : std::tgamma(n + 1.0) / (std::tgamma(k + 1.0) * std::tgamma(n - k + 1.0));
}

/// A plan whose trajectories have closed forms: robot 0 moves linearly on x
/// from -0.5 to 0.5 and as tau^2 on y; robot 1 as tau^3 on z (3D).
std::unique_ptr<flowopt::JointTrajectory> known_plan(unsigned degree, double horizon) {
    auto msg = std::make_unique<flowopt::JointTrajectory>();
    std::memset(msg.get(), 0, sizeof(flowopt::JointTrajectory));
    msg->version = flowopt::WIRE_VERSION;
    msg->status = static_cast<std::uint32_t>(flowopt::PlanStatus::Ok);
    msg->dim = 3;
    msg->robots = 2;
    msg->degree = degree;
    msg->horizon = horizon;
    msg->plan_origin_ns = 5'000'000'000;
    msg->state_timestamp_ns = 5'000'000'000;
    for (unsigned k = 0; k <= degree; ++k) {
        msg->coeffs[0][0][k] = -0.5 + static_cast<double>(k) / degree;  // degree elevation of a line
        msg->coeffs[0][1][k] = binomial(k, 2) / binomial(degree, 2);     // of tau^2
        msg->coeffs[1][2][k] = binomial(k, 3) / binomial(degree, 3);     // of tau^3
    }
    return msg;
}

void check_known_plans() {
    for (unsigned degree : {3u, 10u, 15u}) {
        const double horizon = 2.5;
        auto msg = known_plan(degree, horizon);
        for (double t : {-1.0, 0.0, 0.3, 1.25, 2.0, 2.5, 4.0}) {
            const double tau = std::clamp(t / horizon, 0.0, 1.0);
            const std::string at = " (degree " + std::to_string(degree) + ", t " + std::to_string(t) + ")";
            flowopt::Kinematics k{};
            expect(flowopt::sample_robot(*msg, 0, t, k), "robot 0 samples" + at);
            expect_near(k.position[0], -0.5 + tau, "linear position" + at);
            expect_near(k.velocity[0], 1.0 / horizon, "linear velocity" + at);
            expect_near(k.acceleration[0], 0.0, "linear acceleration" + at);
            expect_near(k.position[1], tau * tau, "quadratic position" + at);
            expect_near(k.velocity[1], 2.0 * tau / horizon, "quadratic velocity" + at);
            expect_near(k.acceleration[1], 2.0 / (horizon * horizon), "quadratic acceleration" + at);
            expect_near(k.position[2], 0.0, "robot 0 z" + at);
            expect(flowopt::sample_robot(*msg, 1, t, k), "robot 1 samples" + at);
            expect_near(k.position[2], tau * tau * tau, "cubic position" + at);
            expect_near(k.velocity[2], 3.0 * tau * tau / horizon, "cubic velocity" + at);
            expect_near(k.acceleration[2], 6.0 * tau / (horizon * horizon), "cubic acceleration" + at);
        }
        // The time since the origin: 1.25 s after plan_origin_ns.
        expect_near(flowopt::elapsed_s(*msg, 6'250'000'000), 1.25, "elapsed_s");
        expect_near(flowopt::elapsed_s(*msg, 4'000'000'000), -1.0, "elapsed_s before the origin");
        flowopt::Kinematics k{};
        expect(!flowopt::sample_robot(*msg, 2, 0.0, k), "no robot 2");
    }
    double row[flowopt::MAX_COEFFS];
    for (double tau : {0.0, 0.2, 0.5, 0.9, 1.0}) {
        double sums[3] = {0, 0, 0};
        for (unsigned order = 0; order < 3; ++order) {
            flowopt::bernstein_row(12, order, tau, row);
            for (unsigned c = 0; c <= 12; ++c) sums[order] += row[c];
        }
        expect_near(sums[0], 1.0, "partition of unity");
        expect(std::fabs(sums[1]) < 1e-9 && std::fabs(sums[2]) < 1e-7, "derivatives of a constant vanish");
    }
}

void check_the_contract() {
    auto msg = known_plan(10, 5.0);
    using flowopt::Decision;
    auto sent = std::make_unique<flowopt::Sent>();
    sent->record(msg->answers_sequence, msg->state_timestamp_ns);
    for (auto status : {flowopt::PlanStatus::Ok, flowopt::PlanStatus::Held, flowopt::PlanStatus::Stopping}) {
        msg->status = static_cast<std::uint32_t>(status);
        expect(flowopt::decide(*msg, *sent) == Decision::Follow, "a followable status is followed");
    }
    ++msg->state_timestamp_ns;
    expect(flowopt::decide(*msg, *sent) == Decision::Ignore, "an answer to another snapshot is ignored");
    --msg->state_timestamp_ns;
    ++msg->answers_sequence;
    expect(flowopt::decide(*msg, *sent) == Decision::Ignore, "an answer to another sequence is ignored");
    --msg->answers_sequence;
    expect(flowopt::decide(*msg, flowopt::Sent{}) == Decision::Ignore, "a controller that sent nothing follows nothing");
    auto ring = std::make_unique<flowopt::Sent>();
    for (std::uint64_t k = 0; k <= flowopt::Sent::REMEMBERED; ++k) {
        ring->record(k, 1000 + k);
    }
    expect(!ring->contains(0, 1000) && ring->contains(1, 1001), "the oldest snapshot is forgotten");
    msg->status = static_cast<std::uint32_t>(flowopt::PlanStatus::NoPlan);
    flowopt::Kinematics k{};
    expect(flowopt::decide(*msg, *sent) == Decision::Rest && !flowopt::sample_robot(*msg, 0, 0.0, k), "NoPlan: rest");
    msg->status = 9;
    expect(flowopt::decide(*msg, *sent) == Decision::Rest, "an unknown status: rest");
    msg->status = 1;
    msg->degree = 16;
    expect(flowopt::decide(*msg, *sent) == Decision::Rest, "an impossible degree: rest");
    msg->degree = 10;
    msg->horizon = std::nan("");
    expect(flowopt::decide(*msg, *sent) == Decision::Rest, "a NaN horizon: rest");
    expect(flowopt::is_rejection(6) && flowopt::is_rejection(16) && !flowopt::is_rejection(19) && flowopt::is_rejection(25) && flowopt::is_rejection(26) && !flowopt::is_rejection(24) && !flowopt::is_rejection(27), "rejections");

    flowopt::StateSnapshot snapshot{};
    expect(flowopt::set_team(snapshot.team, "lab-a") && flowopt::team_name(snapshot.team) == "lab-a", "team name");
    expect(!flowopt::set_team(snapshot.team, "a/b") && !flowopt::set_team(snapshot.team, std::string(33, 'x')),
           "bad team names are refused");
    expect(std::string(flowopt::StateSnapshot::IOX2_TYPE_NAME) == "flowopt::StateSnapshot" &&
               std::string(flowopt::JointTrajectory::IOX2_TYPE_NAME) == "flowopt::JointTrajectory",
           "type names");
}

void print_number(double x) {
    if (std::isfinite(x)) {
        std::printf("%.17g", x);
    } else {
        std::printf("null");
    }
}

int evaluate(const char* path, int count, char** times) {
    std::vector<char> bytes;
    if (std::string(path) == "-") {
        bytes.assign(std::istreambuf_iterator<char>(std::cin), std::istreambuf_iterator<char>());
    } else {
        std::ifstream in(path, std::ios::binary);
        if (!in) {
            std::cerr << "check: cannot read " << path << "\n";
            return 2;
        }
        bytes.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
    }
    if (bytes.size() != sizeof(flowopt::JointTrajectory)) {
        std::cerr << "check: a JointTrajectory is " << sizeof(flowopt::JointTrajectory) << " bytes, got "
                  << bytes.size() << "\n";
        return 2;
    }
    auto msg = std::make_unique<flowopt::JointTrajectory>();
    std::memcpy(msg.get(), bytes.data(), bytes.size());
    std::printf("{\"status\":%u,\"reason\":%u,\"dim\":%u,\"robots\":%u,\"degree\":%u,\"plan_origin_ns\":%llu,"
                "\"horizon\":",
                msg->status, msg->reason, msg->dim, msg->robots, msg->degree,
                static_cast<unsigned long long>(msg->plan_origin_ns));
    print_number(msg->horizon);
    std::printf(",\"samples\":[");
    for (int i = 0; i < count && flowopt::has_plan(*msg); ++i) {
        const double t = std::strtod(times[i], nullptr);
        std::printf("%s{\"t\":", i ? "," : "");
        print_number(t);
        const char* names[3] = {"position", "velocity", "acceleration"};
        for (int order = 0; order < 3; ++order) {
            std::printf(",\"%s\":[", names[order]);
            for (std::uint32_t r = 0; r < msg->robots; ++r) {
                flowopt::Kinematics k{};
                flowopt::sample_robot(*msg, r, t, k);
                const double* v = order == 0 ? k.position : order == 1 ? k.velocity : k.acceleration;
                std::printf("%s[", r ? "," : "");
                for (std::uint32_t a = 0; a < msg->dim; ++a) {
                    std::printf("%s", a ? "," : "");
                    print_number(v[a]);
                }
                std::printf("]");
            }
            std::printf("]");
        }
        std::printf("}");
    }
    std::printf("]}\n");
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc > 1) {
        return evaluate(argv[1], argc - 2, argv + 2);
    }
    check_known_plans();
    check_the_contract();
    std::printf("%s: %d of %d checks passed\n", failures ? "FAILED" : "ok", checks - failures, checks);
    return failures ? 1 : 0;
}
