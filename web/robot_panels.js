// Kind-specific panels: a small registry keyed by robot kind. The core console knows every robot
// through GET /robots (joints, modes, configuration); a plug-in robot with state of its own (a
// continuum robot's disks, an ultrasound arm's sweep) brings a panel module here, loaded only when
// such a robot is selected. The panel gets a side-panel tab of its own ("tab-robot"), the 3D view,
// the REST client and the stream: it names the topics it wants and receives their newest message
// once per animation frame (or every message, for the topics it lists in `everyMessage`).
//
// A panel module exports createPanel(root, ctx) returning an object with
//   topics: string[]                  topics to subscribe (newest message per frame)
//   everyMessage?: string[]           topics whose every message is passed (small, for plots)
//   onMessage(topic, msg, stampMs)    a decoded JSON message
//   setCommandable(ok, hint)          commands allowed (lease, fresh data, not a viewer) or why not
//   destroy()                         the robot changed: remove what the panel drew
// ctx: {api, robot, view() (the CatheterView or null), status(text, kind), commandable()}.

const REGISTRY = [
  {kind: 'sdu_continuum', title: 'Continuum', load: () => import('./continuum.js')},
  // The ultrasound arm is a serial arm whose GET /robots entry has an "ultrasound" section.
  {kind: 'serial_arm', when: (robot) => !!robot.ultrasound, title: 'Ultrasound', load: () => import('./ultrasound.js')},
];

export function panelFor(robot) {
  if (!robot) return null;
  return REGISTRY.find((e) => e.kind === robot.kind && (!e.when || e.when(robot))) || null;
}
