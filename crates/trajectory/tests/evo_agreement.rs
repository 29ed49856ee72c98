//! Agreement with evo 1.38.1 on real trajectories (`../shared/data/trajectories`, KITTI 00 ORB
//! estimate). The reference numbers were printed by evo itself (`--save_results`, stats.json and
//! the error array length), with these commands (GT, EST as named in each test):
//!
//! ```text
//! evo_ape tum GT EST [-a | -as]
//! evo_rpe tum GT EST --delta 1 --delta_unit f [-r angle_deg]
//! evo_rpe tum GT EST --delta 10 --delta_unit f -a
//! evo_rpe tum GT EST --delta 0.5 --delta_unit m -as [-r angle_deg]
//! evo_ape kitti GT EST -a | -as ;  evo_rpe kitti GT EST --delta 1 --delta_unit f [-r angle_deg]
//! evo_ape euroc GT.csv EST.tum -a | -as ;  evo_rpe euroc GT.csv EST.tum --delta 1 --delta_unit f
//! ```
//!
//! The tests never call Python.

use std::path::PathBuf;
use stillpoint_trajectory::{
    Alignment, AteOptions, DeltaUnit, ErrorStats, Matching, RpeOptions, TrajectoryFormat, ate,
    read_trajectory_lenient, rpe,
};

fn shared() -> PathBuf {
    std::env::var_os("STILLPOINT_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared"))
}

/// evo's statistics of one run.
struct Evo {
    count: usize,
    rmse: f64,
    mean: f64,
    median: f64,
    std: f64,
    min: f64,
    max: f64,
    sse: f64,
}

/// Every statistic within 1e-6 (of its unit: m, deg, or m² for sse), equal pair count.
fn assert_agrees(what: &str, ours: &ErrorStats, evo: &Evo) {
    assert_eq!(ours.count, evo.count, "{what}: pair count");
    for (name, a, b) in [
        ("rmse", ours.rmse, evo.rmse),
        ("mean", ours.mean, evo.mean),
        ("median", ours.median, evo.median),
        ("std", ours.std, evo.std),
        ("min", ours.min, evo.min),
        ("max", ours.max, evo.max),
        ("sse", ours.sse, evo.sse),
    ] {
        assert!(
            (a - b).abs() <= 1e-6,
            "{what}: {name} ours {a} evo {b} (diff {:e})",
            a - b
        );
    }
}

const E_APE_SE3: Evo = Evo {
    count: 798,
    rmse: 0.09172711520685733,
    mean: 0.08152162194619834,
    median: 0.07791194901949527,
    std: 0.042048648247395404,
    min: 0.002619987097383053,
    max: 0.25581673381397085,
    sse: 6.714263204009318,
};
const E_APE_SIM3: Evo = Evo {
    count: 798,
    rmse: 0.08384138804295284,
    mean: 0.0748410847826337,
    median: 0.07194517866622532,
    std: 0.03779140613324187,
    min: 0.0070002905794235674,
    max: 0.22665179238276975,
    sse: 5.609443922477258,
};
const E_RPE_T: Evo = Evo {
    count: 797,
    rmse: 0.015076710159641325,
    mean: 0.006106922465380456,
    median: 0.004183939336058311,
    std: 0.01378450895896054,
    min: 0.00011469502653262393,
    max: 0.21740892442745757,
    sse: 0.18116382982255205,
};
const FR1_APE_NONE: Evo = Evo {
    count: 785,
    rmse: 0.020079418378506592,
    mean: 0.01806251843069654,
    median: 0.016517756173282168,
    std: 0.008770887660884508,
    min: 0.0012561023047507462,
    max: 0.04328943388403233,
    sse: 0.31649868829899996,
};
const FR1_APE_SE3: Evo = Evo {
    count: 785,
    rmse: 0.013470088849733695,
    mean: 0.012024498709110232,
    median: 0.011183186775061079,
    std: 0.006070809205890624,
    min: 0.0009550461813178077,
    max: 0.03475954589500904,
    sse: 0.14243298549148023,
};
const FR1_APE_SIM3: Evo = Evo {
    count: 785,
    rmse: 0.013389384904168217,
    mean: 0.011986889624888907,
    median: 0.011133899090810867,
    std: 0.005965744315062322,
    min: 0.000732706705229504,
    max: 0.03484614485226119,
    sse: 0.14073136806789466,
};
const FR1_RPE_M: Evo = Evo {
    count: 17,
    rmse: 0.024659780837899554,
    mean: 0.02336683927599075,
    median: 0.02362336817879471,
    std: 0.00788007698079493,
    min: 0.003832935131437015,
    max: 0.036497612241952804,
    sse: 0.010337781446545048,
};
const FR1_RPE_R: Evo = Evo {
    count: 784,
    rmse: 0.35361316104479856,
    mean: 0.3003065811400405,
    median: 0.262138999669449,
    std: 0.186703575188251,
    min: 0.016937143523711364,
    max: 1.6332960623334578,
    sse: 98.0331378486502,
};
const FR1_RPE_RM: Evo = Evo {
    count: 17,
    rmse: 0.9592611573141747,
    mean: 0.9080975405449552,
    median: 0.8485749345919869,
    std: 0.3090967887053071,
    min: 0.4897545488820215,
    max: 1.6134769163134866,
    sse: 15.643093454839407,
};
const FR1_RPE_T: Evo = Evo {
    count: 784,
    rmse: 0.0057643708489283196,
    mean: 0.004815609470203964,
    median: 0.004138857799364448,
    std: 0.0031682608343468967,
    min: 0.00017106115346223795,
    max: 0.020865814532329833,
    sse: 0.02605072948663608,
};
const FR1_RPE_T10: Evo = Evo {
    count: 78,
    rmse: 0.014610132023888821,
    mean: 0.012477076968475921,
    median: 0.011981234060699723,
    std: 0.007601217539196553,
    min: 0.0010349715017427567,
    max: 0.04315386173025472,
    sse: 0.01664956470492601,
};
const FR2_APE_NONE: Evo = Evo {
    count: 2174,
    rmse: 3.17399354190223,
    mean: 2.9496938875994747,
    median: 2.594642464975095,
    std: 1.1719816438389132,
    min: 1.4603442833644174,
    max: 5.066735062280106,
    sse: 21901.386898776578,
};
const FR2_APE_SE3: Evo = Evo {
    count: 2174,
    rmse: 0.008118977562045396,
    mean: 0.007491776870216619,
    median: 0.0074146298293173854,
    std: 0.0031290695070394156,
    min: 0.00034963619840638655,
    max: 0.024299593694385224,
    sse: 0.14330528992361463,
};
const FR2_APE_SIM3: Evo = Evo {
    count: 2174,
    rmse: 0.006123163030157291,
    mean: 0.005586197318706158,
    median: 0.005305225075852879,
    std: 0.0025074937707530087,
    min: 0.0001897958096084112,
    max: 0.021476785562787627,
    sse: 0.08151005482370602,
};
const FR2_RPE_M: Evo = Evo {
    count: 36,
    rmse: 0.009446121683277691,
    mean: 0.008755349476210915,
    median: 0.008116801333983757,
    std: 0.003545852563869826,
    min: 0.001514973246316643,
    max: 0.021004759497588513,
    sse: 0.003212251734790403,
};
const FR2_RPE_R: Evo = Evo {
    count: 2173,
    rmse: 0.28051922626732667,
    mean: 0.2295561195809192,
    median: 0.18781845711906164,
    std: 0.16122972513953607,
    min: 0.0060389459196583985,
    max: 1.259403502708011,
    sse: 170.99562189211142,
};
const FR2_RPE_RM: Evo = Evo {
    count: 36,
    rmse: 0.6071347107060898,
    mean: 0.5353915314291497,
    median: 0.453786241079732,
    std: 0.28630135350381597,
    min: 0.12568090269045482,
    max: 1.341994881007253,
    sse: 13.270052049990024,
};
const FR2_RPE_T: Evo = Evo {
    count: 2173,
    rmse: 0.0034903213747872943,
    mean: 0.003038087417500967,
    median: 0.002750288386204023,
    std: 0.0017182456584898947,
    min: 0.00013196900558823892,
    max: 0.01948467892016712,
    sse: 0.026472231989372527,
};
const FR2_RPE_T10: Evo = Evo {
    count: 217,
    rmse: 0.006234649485655027,
    mean: 0.00543000592376204,
    median: 0.004879600973947235,
    std: 0.003063639971812557,
    min: 0.000751642811411404,
    max: 0.021287541537058963,
    sse: 0.008434975363348331,
};
const K_APE_SE3: Evo = Evo {
    count: 4541,
    rmse: 1.303449714565045,
    mean: 1.1569971285389946,
    median: 1.0656247695558074,
    std: 0.6002822693968386,
    min: 0.06931322021483205,
    max: 3.587949120678975,
    sse: 7715.073440293025,
};
const K_APE_SIM3: Evo = Evo {
    count: 4541,
    rmse: 0.937709073611404,
    mean: 0.8726926319693136,
    median: 0.8446910134863976,
    std: 0.3430829008266512,
    min: 0.17951466687995615,
    max: 2.693499863613383,
    sse: 3992.8936108752687,
};
const K_RPE_R: Evo = Evo {
    count: 4540,
    rmse: 0.11497352125979227,
    mean: 0.059583454923114204,
    median: 0.04107440527534105,
    std: 0.09832966231153813,
    min: 0.0022435537758804243,
    max: 2.196615406942412,
    sse: 60.01385408257661,
};
const K_RPE_T: Evo = Evo {
    count: 4540,
    rmse: 0.028120377017393856,
    mean: 0.019301310981393958,
    median: 0.01470904343858892,
    std: 0.020450305572286533,
    min: 0.00031240026309761656,
    max: 0.30271249059536337,
    sse: 3.5900304403456915,
};

struct Case {
    gt: PathBuf,
    est: PathBuf,
    gt_format: TrajectoryFormat,
    est_format: TrajectoryFormat,
    matching: Matching,
}

fn case(gt: &str, est: &str, gt_format: TrajectoryFormat, est_format: TrajectoryFormat) -> Case {
    let root = shared().join("data");
    let matching = if gt_format == TrajectoryFormat::Kitti {
        Matching::ByIndex
    } else {
        Matching::default()
    };
    Case {
        gt: root.join(gt),
        est: root.join(est),
        gt_format,
        est_format,
        matching,
    }
}

fn check_ate(c: &Case, align: Alignment, evo: &Evo, what: &str) {
    let gt = read_trajectory_lenient(&c.gt, c.gt_format).unwrap().0;
    let est = read_trajectory_lenient(&c.est, c.est_format).unwrap().0;
    let r = ate(
        &gt,
        &est,
        &AteOptions {
            align,
            matching: c.matching,
        },
    )
    .unwrap();
    eprintln!("{what}: ours {:?}", r.stats);
    assert_agrees(what, &r.stats, evo);
}

fn check_rpe(
    c: &Case,
    align: Alignment,
    delta: f64,
    unit: DeltaUnit,
    t: Option<&Evo>,
    r: Option<&Evo>,
    what: &str,
) {
    let gt = read_trajectory_lenient(&c.gt, c.gt_format).unwrap().0;
    let est = read_trajectory_lenient(&c.est, c.est_format).unwrap().0;
    let res = rpe(
        &gt,
        &est,
        &RpeOptions {
            align,
            matching: c.matching,
            delta,
            delta_unit: unit,
        },
    )
    .unwrap();
    eprintln!(
        "{what}: ours t {:?}\n  r {:?}",
        res.translation, res.rotation_deg
    );
    if let Some(t) = t {
        assert_agrees(&format!("{what} translation"), &res.translation, t);
    }
    if let Some(r) = r {
        assert_agrees(&format!("{what} rotation"), &res.rotation_deg, r);
    }
}

fn fr2() -> Case {
    case(
        "trajectories/tum/rgbd_dataset_freiburg2_desk_groundtruth.txt",
        "trajectories/tum/fr2_desk_ORB_estimate_evo.txt",
        TrajectoryFormat::Tum,
        TrajectoryFormat::Tum,
    )
}

fn fr1() -> Case {
    case(
        "trajectories/tum/rgbd_dataset_freiburg1_xyz_groundtruth.txt",
        "trajectories/tum/fr1_xyz_rgbdslam_estimate_evo.txt",
        TrajectoryFormat::Tum,
        TrajectoryFormat::Tum,
    )
}

#[test]
#[ignore = "needs ../shared/data"]
fn fr2_desk_orb_matches_evo() {
    let c = fr2();
    check_ate(&c, Alignment::None, &FR2_APE_NONE, "fr2 ape");
    check_ate(&c, Alignment::Se3, &FR2_APE_SE3, "fr2 ape -a");
    check_ate(&c, Alignment::Sim3, &FR2_APE_SIM3, "fr2 ape -as");
    check_rpe(
        &c,
        Alignment::None,
        1.0,
        DeltaUnit::Frames,
        Some(&FR2_RPE_T),
        Some(&FR2_RPE_R),
        "fr2 rpe 1 f",
    );
    check_rpe(
        &c,
        Alignment::Se3,
        10.0,
        DeltaUnit::Frames,
        Some(&FR2_RPE_T10),
        None,
        "fr2 rpe 10 f -a",
    );
    check_rpe(
        &c,
        Alignment::Sim3,
        0.5,
        DeltaUnit::Metres,
        Some(&FR2_RPE_M),
        Some(&FR2_RPE_RM),
        "fr2 rpe 0.5 m -as",
    );
}

#[test]
#[ignore = "needs ../shared/data"]
fn fr1_xyz_rgbdslam_matches_evo() {
    let c = fr1();
    check_ate(&c, Alignment::None, &FR1_APE_NONE, "fr1 ape");
    check_ate(&c, Alignment::Se3, &FR1_APE_SE3, "fr1 ape -a");
    check_ate(&c, Alignment::Sim3, &FR1_APE_SIM3, "fr1 ape -as");
    check_rpe(
        &c,
        Alignment::None,
        1.0,
        DeltaUnit::Frames,
        Some(&FR1_RPE_T),
        Some(&FR1_RPE_R),
        "fr1 rpe 1 f",
    );
    check_rpe(
        &c,
        Alignment::Se3,
        10.0,
        DeltaUnit::Frames,
        Some(&FR1_RPE_T10),
        None,
        "fr1 rpe 10 f -a",
    );
    check_rpe(
        &c,
        Alignment::Sim3,
        0.5,
        DeltaUnit::Metres,
        Some(&FR1_RPE_M),
        Some(&FR1_RPE_RM),
        "fr1 rpe 0.5 m -as",
    );
}

#[test]
#[ignore = "needs ../shared/data"]
fn kitti_00_orb_matches_evo() {
    let c = case(
        "kitti/odometry_gt_poses/poses_12col/00.txt",
        "kitti/odometry_gt_poses/00_ORB_estimate_from_evo.txt",
        TrajectoryFormat::Kitti,
        TrajectoryFormat::Kitti,
    );
    check_ate(&c, Alignment::Se3, &K_APE_SE3, "kitti ape -a");
    check_ate(&c, Alignment::Sim3, &K_APE_SIM3, "kitti ape -as");
    check_rpe(
        &c,
        Alignment::None,
        1.0,
        DeltaUnit::Frames,
        Some(&K_RPE_T),
        Some(&K_RPE_R),
        "kitti rpe 1 f",
    );
}

#[test]
#[ignore = "needs ../shared/data"]
fn euroc_v102_matches_evo() {
    let c = case(
        "trajectories/euroc/V1_02_groundtruth.csv",
        "trajectories/euroc/V102_estimate_evo.txt",
        TrajectoryFormat::Euroc,
        TrajectoryFormat::Tum,
    );
    check_ate(&c, Alignment::Se3, &E_APE_SE3, "euroc ape -a");
    check_ate(&c, Alignment::Sim3, &E_APE_SIM3, "euroc ape -as");
    check_rpe(
        &c,
        Alignment::None,
        1.0,
        DeltaUnit::Frames,
        Some(&E_RPE_T),
        None,
        "euroc rpe 1 f",
    );
}
