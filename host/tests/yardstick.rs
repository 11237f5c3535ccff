//! The offline yardstick and the online core on the recorded samples and the
//! synthetic office: the paper's known answers, every solver's coverage, and
//! the online selector's size against in-order, greedy and exact.

use placedb_host::pipeline::{self, Outcome, Prepared, Solver, SolverParams};
use placedb_host::read::{self, ReadOptions};
use placedb_host::synth::{self, SynthConfig};
use placedb_host::testing::data;
use placedb_host::{GridOrigin, Sequence, VoxelConfig};
use std::sync::OnceLock;

fn open(name: &str) -> Sequence {
    read::open(&data(name), &ReadOptions::default()).expect("sample reads")
}

/// The demo office (`placedb select --demo`): the README's synthetic rows.
fn synthetic() -> Sequence {
    synth::sequence(&SynthConfig::demo())
}

fn prepared(seq: &Sequence, origin: GridOrigin) -> Prepared {
    let cfg = VoxelConfig {
        origin,
        ..VoxelConfig::default()
    };
    pipeline::prepare(seq, cfg, true).expect("voxelizes")
}

struct Case {
    seq: Sequence,
    prep: Prepared,
    /// `runs[m][s]`: solver `SOLVERS[s]` at mu `MUS[m]`.
    runs: Vec<Vec<Outcome>>,
}

const MUS: [f32; 3] = [0.1, 0.3, 0.5];
const SOLVERS: [Solver; 4] = [
    Solver::InOrder,
    Solver::Greedy,
    Solver::Exact,
    Solver::Online,
];

impl Case {
    fn new(seq: Sequence, origin: GridOrigin, solvers: &[Solver]) -> Case {
        let prep = prepared(&seq, origin);
        let runs = MUS
            .iter()
            .map(|&mu| solvers.iter().map(|&s| run(&seq, &prep, s, mu)).collect())
            .collect();
        Case { seq, prep, runs }
    }

    fn outcome(&self, solver: Solver, mu: f32) -> &Outcome {
        let m = MUS.iter().position(|&x| x == mu).expect("a tested mu");
        self.runs[m]
            .iter()
            .find(|o| o.solver == solver)
            .expect("a tested solver")
    }

    fn size(&self, solver: Solver, mu: f32) -> usize {
        self.outcome(solver, mu).metrics.size
    }
}

/// The README's Results cases (world-anchored grid), each sample voxelized
/// and solved once for the whole file.
fn cases() -> &'static [Case] {
    static CASES: OnceLock<Vec<Case>> = OnceLock::new();
    CASES.get_or_init(|| {
        [open("7scenes-1000"), synthetic(), open("vprdb-test-db")]
            .into_iter()
            .map(|seq| Case::new(seq, GridOrigin::World, &SOLVERS))
            .collect()
    })
}

fn run(seq: &Sequence, prep: &Prepared, solver: Solver, mu: f32) -> Outcome {
    let params = SolverParams::default();
    pipeline::solve(seq, prep, solver, mu, &params, true).expect("solves")
}

#[test]
fn reference_code_answers_on_its_own_test_data() {
    // The reference code anchors the grid at the scene's minimum corner.
    let seq = open("vprdb-test-db");
    let prep = prepared(&seq, GridOrigin::SceneMin);
    assert_eq!(
        run(&seq, &prep, Solver::InOrder, 0.05).database,
        vec![0, 1, 3]
    );
    assert_eq!(run(&seq, &prep, Solver::InOrder, 0.5).metrics.size, 4);
    assert_eq!(run(&seq, &prep, Solver::InOrder, 0.8).metrics.size, 5);
}

/// The README's "for scale" sentence: with the reference code's grid
/// anchoring (`placedb compare ../shared/data/7scenes-1000 --grid-origin
/// scene-min --mu 0.1,0.3,0.5`), in-order / greedy / exact on 7scenes-1000.
#[test]
fn paper_answers_on_7scenes_with_the_scene_min_grid() {
    let solvers = [Solver::InOrder, Solver::Greedy, Solver::Exact];
    let case = Case::new(open("7scenes-1000"), GridOrigin::SceneMin, &solvers);
    let sizes = |s| MUS.map(|mu| case.size(s, mu));
    assert_eq!(
        sizes(Solver::InOrder),
        [2, 4, 15],
        "in-order (the paper's code)"
    );
    assert_eq!(sizes(Solver::Greedy), [1, 3, 11], "greedy");
    assert_eq!(sizes(Solver::Exact), [1, 2, 8], "exact");
}

#[test]
fn every_solver_covers_every_frame_and_labels_overlap() {
    for case in cases() {
        for mu in MUS {
            let graph = case.prep.co.graph(mu);
            let exact = case.outcome(Solver::Exact, mu);
            assert!(
                exact.exact.is_some_and(|(optimal, _)| optimal),
                "{} exact not proven",
                case.seq.name
            );
            assert!(
                exact.metrics.size <= case.size(Solver::Greedy, mu),
                "{} mu {mu}",
                case.seq.name
            );
            for solver in SOLVERS {
                let o = case.outcome(solver, mu);
                let name = format!("{} {} mu {mu}", case.seq.name, solver.name());
                assert_eq!(o.metrics.uncovered, 0, "{name}");
                assert_eq!(o.labels.len(), case.seq.frames.len(), "{name}");
                for (f, &l) in o.labels.iter().enumerate() {
                    assert!(
                        o.database.binary_search(&l).is_ok(),
                        "{name}: label {l} of {f} not in database"
                    );
                    if l != f {
                        assert!(
                            graph.has_edge(f, l),
                            "{name}: frame {f} does not overlap its label {l}"
                        );
                    }
                }
            }
        }
    }
}

/// The README's Results table, cell by cell (`placedb compare SEQ --mu
/// 0.1,0.3,0.5`, the synthetic scan with `--demo`): database sizes of
/// in-order, greedy, exact and online (ram512k, window 32).
#[test]
fn the_readme_results_table() {
    let table: [(&str, [[usize; 4]; 3]); 3] = [
        ("7scenes-1000", [[2, 1, 1, 2], [4, 3, 2, 4], [14, 9, 7, 10]]),
        (
            "synthetic",
            [[23, 18, 14, 19], [60, 41, 35, 42], [121, 95, 85, 98]],
        ),
        ("vprdb-test-db", [[4, 4, 4, 4], [4, 4, 4, 4], [4, 4, 4, 4]]),
    ];
    for (case, (name, rows)) in cases().iter().zip(table) {
        assert_eq!(case.seq.name, name);
        for (mu, row) in MUS.into_iter().zip(rows) {
            assert_eq!(SOLVERS.map(|s| case.size(s, mu)), row, "{name} mu {mu}");
        }
    }
}

/// Issue 3's targets as the README states them: online never larger than
/// in-order, and within 5 % of greedy summed over the README's cases.
#[test]
fn online_beats_in_order_and_stays_near_greedy() {
    let (mut online_sum, mut greedy_sum, mut exact_sum) = (0, 0, 0);
    for case in cases() {
        for mu in MUS {
            let online = case.size(Solver::Online, mu);
            let in_order = case.size(Solver::InOrder, mu);
            let greedy = case.size(Solver::Greedy, mu);
            let exact = case.size(Solver::Exact, mu);
            println!(
                "{:<14} mu {mu}: online {online} in-order {in_order} greedy {greedy} exact {exact}",
                case.seq.name
            );
            assert!(
                online <= in_order,
                "{} mu {mu}: online {online} > in-order {in_order}",
                case.seq.name
            );
            online_sum += online;
            greedy_sum += greedy;
            exact_sum += exact;
        }
    }
    println!("sums: online {online_sum} greedy {greedy_sum} exact {exact_sum}");
    assert!(
        online_sum as f64 <= 1.05 * greedy_sum as f64,
        "online {online_sum} > 1.05 x greedy {greedy_sum}"
    );
}

/// Issue 3's sketch target: on a board whose key pool is too small for the
/// scan (ram256k on the demo office walked for 1,500 frames: some windows
/// hold more voxels than its pool), frames fall back to sketches, and yet at
/// most 1 % of the frames get a label whose exact IoU is not above mu, and
/// none below mu - 0.05.
#[test]
fn sketch_mode_keeps_labels_close_to_mu() {
    let seq = synth::sequence(&SynthConfig {
        frames: 1500,
        ..SynthConfig::demo()
    });
    let prep = prepared(&seq, GridOrigin::World);
    let params = SolverParams {
        profile: "ram256k".into(),
        ..SolverParams::default()
    };
    let mut sketched = 0;
    for mu in [0.1, 0.3, 0.5] {
        let o = pipeline::solve(&seq, &prep, Solver::Online, mu, &params, true).expect("solves");
        let st = o.online.as_ref().expect("online run").status;
        sketched += st.sketch_compared_frames;
        println!(
            "ram256k mu {mu}: size {} sketched {} measured by sketch {} labels below mu {} min label IoU {:.3}",
            o.metrics.size,
            st.sketched_frames,
            st.sketch_compared_frames,
            o.labels_below_mu,
            o.label_iou_min
        );
        assert!(
            o.labels_below_mu as f64 <= 0.01 * seq.frames.len() as f64,
            "mu {mu}"
        );
        assert!(o.label_iou_min >= mu - 0.05, "mu {mu}: {}", o.label_iou_min);
        assert_eq!(st.uncovered_frames, 0, "mu {mu}: database full");
    }
    assert!(
        sketched > 0,
        "no frame was measured by sketch: the test does not exercise sketches"
    );
}

/// `oracle_recall@0.3` of a dominating set at mu >= 0.3, tested on its own
/// sequence, is exactly 1: IoU > mu implies coverage s(q, b) >= IoU > 0.3.
/// The cube baseline, without the guarantee, falls below on some scan.
#[test]
fn oracle_recall_on_the_scan_itself() {
    let mut cube_recalls = Vec::new();
    for case in cases().iter().filter(|c| c.seq.frames.len() < 1000) {
        let test = pipeline::prepare_test(&case.seq, &case.prep, true).expect("voxelizes");
        for solver in SOLVERS {
            let mut o = case.outcome(solver, 0.3).clone();
            pipeline::add_oracle_recall(&mut o, &case.prep, &test);
            assert_eq!(
                o.metrics.oracle_recall_0_3,
                Some(1.0),
                "{} {}",
                case.seq.name,
                solver.name()
            );
        }
        let mut cube = run(&case.seq, &case.prep, Solver::Cube, 0.3);
        pipeline::add_oracle_recall(&mut cube, &case.prep, &test);
        let r = cube.metrics.oracle_recall_0_3.expect("computed");
        println!("{}: cube oracle_recall@0.3 {r}", case.seq.name);
        cube_recalls.push(r);
    }
    assert!(
        cube_recalls.iter().any(|&r| r < 1.0),
        "the cube baseline never fell below 1: {cube_recalls:?}"
    );
}
