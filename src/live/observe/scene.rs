//! The team as a Foxglove scene (`foxglove.SceneUpdate`, protobuf): the
//! robots where the newest snapshot measured them, their goals, the
//! obstacles it reported, and the followed plan's paths, coloured by the
//! newest answer's status. Foxglove's 3D panel draws it from a recording or
//! the live WebSocket.

use foxglove::messages::{
    Color, CylinderPrimitive, LinePrimitive, Point3, Pose, Quaternion, SceneEntity, SceneUpdate, SpherePrimitive,
    TextPrimitive, Vector3, line_primitive,
};

use flowopt_client::records::{AnswerRecord, SnapshotRecord};
use flowopt_planner::plan::JointPlan;

/// Points drawn along each robot's plan.
const PATH_POINTS: usize = 32;
/// The frame everything is drawn in.
pub const FRAME: &str = "world";

fn colour(r: f64, g: f64, b: f64, a: f64) -> Option<Color> {
    Some(Color { r, g, b, a })
}

fn pose(p: [f64; 3]) -> Option<Pose> {
    Some(Pose {
        position: Some(Vector3 { x: p[0], y: p[1], z: p[2] }),
        orientation: Some(Quaternion { x: 0.0, y: 0.0, z: 0.0, w: 1.0 }),
    })
}

fn entity(id: &str, team: &str) -> SceneEntity {
    SceneEntity { frame_id: FRAME.into(), id: format!("{team}/{id}"), ..Default::default() }
}

/// The robots, their goals and the obstacles of `s`; robots are spheres of
/// `radius`.
pub fn snapshot(s: &SnapshotRecord, radius: f64) -> SceneUpdate {
    let d = 2.0 * radius;
    let mut robots = entity("robots", &s.team);
    robots.spheres = s
        .robots
        .iter()
        .map(|r| SpherePrimitive {
            pose: pose(r.position),
            size: Some(Vector3 { x: d, y: d, z: d }),
            color: colour(0.15, 0.45, 0.85, 0.9),
        })
        .collect();
    let mut goals = entity("goals", &s.team);
    goals.spheres = s
        .robots
        .iter()
        .map(|r| SpherePrimitive {
            pose: pose(r.goal),
            size: Some(Vector3 { x: d * 0.4, y: d * 0.4, z: d * 0.4 }),
            color: colour(0.2, 0.7, 0.3, 0.6),
        })
        .collect();
    let mut obstacles = entity("obstacles", &s.team);
    obstacles.cylinders = s
        .obstacles
        .iter()
        .map(|o| {
            let height = if s.dim == 3 { 2.0 * o.half_height } else { 0.05 };
            CylinderPrimitive {
                pose: pose(o.position),
                size: Some(Vector3 { x: 2.0 * o.radius, y: 2.0 * o.radius, z: height }),
                bottom_scale: 1.0,
                top_scale: 1.0,
                color: colour(0.85, 0.3, 0.2, 0.8),
            }
        })
        .collect();
    SceneUpdate { entities: vec![robots, goals, obstacles], ..Default::default() }
}

/// The paths of the plan to follow (none: no paths) and the status of
/// `answer` as a label.
pub fn plan(answer: &AnswerRecord, plan: Option<&JointPlan>) -> SceneUpdate {
    let mut paths = entity("plan", &answer.team);
    let (r, g, b) = if answer.status == "Ok" { (0.1, 0.6, 0.9) } else { (0.9, 0.6, 0.1) };
    let Some(plan) = plan else {
        return SceneUpdate { entities: vec![paths, status(answer)], ..Default::default() };
    };
    // Every robot at each instant, evaluated once per instant.
    let instants: Vec<_> = (0..=PATH_POINTS).map(|k| plan.at(plan.horizon * k as f64 / PATH_POINTS as f64)).collect();
    paths.lines = (0..plan.robots)
        .map(|i| LinePrimitive {
            r#type: line_primitive::Type::LineStrip as i32,
            pose: pose([0.0; 3]),
            thickness: 2.0,
            scale_invariant: true,
            points: instants
                .iter()
                .map(|at| Point3 { x: at[i].position.x, y: at[i].position.y, z: at[i].position.z })
                .collect(),
            color: colour(r, g, b, 0.8),
            ..Default::default()
        })
        .collect();
    SceneUpdate { entities: vec![paths, status(answer)], ..Default::default() }
}

/// The newest answer's status and reason, as a label.
pub fn status(answer: &AnswerRecord) -> SceneEntity {
    let mut label = entity("status", &answer.team);
    label.texts = vec![TextPrimitive {
        pose: pose([0.0, 0.0, 0.5]),
        billboard: true,
        font_size: 14.0,
        scale_invariant: true,
        color: colour(0.1, 0.1, 0.1, 1.0),
        text: format!("{} {} {} ({:.1} ms)", answer.team, answer.status, answer.reason, answer.answer_ms),
    }];
    label
}
