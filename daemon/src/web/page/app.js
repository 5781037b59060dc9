// markerd's web page: polls /state.json twice a second and shows the rig,
// the sweep, the detections and the last run's report; the preview is the
// <img> on /preview.mjpg, which the browser draws frame by frame. Plain
// JavaScript, no framework: markerd serves this file as it is.
'use strict';

const $ = (id) => document.getElementById(id);
let updates = 0;
let reportRun = null;

function number(value, digits) {
  return typeof value === 'number' && isFinite(value) ? value.toFixed(digits) : '?';
}

function axisText(axis) {
  if (!axis) return ['\u2013', ''];
  const position = `${number(axis.position, 1)} ${axis.unit || ''}`;
  const words = [axis.state];
  if (!axis.homed) words.push('not homed');
  if (axis.settled) words.push('settled');
  if (axis.fault) words.push('fault: ' + axis.fault);
  return [position, words.join(', ')];
}

function showRig(state) {
  const rig = state.rig;
  const [railPosition, railState] = axisText(rig && rig.rail);
  const [turnPosition, turnState] = axisText(rig && rig.turntable);
  $('rail-position').textContent = rig ? railPosition : 'no rig';
  $('rail-state').textContent = railState;
  $('turntable-position').textContent = rig ? turnPosition : 'no rig';
  $('turntable-state').textContent = turnState;
  const truth = rig && rig.ground_truth;
  $('truth').textContent = truth
    ? `distance ${number(truth.distance_m, 3)} m, yaw ${number(truth.yaw_deg, 1)} deg` : '\u2013';
}

function showFrame(state) {
  const frame = state.frame;
  const camera = state.camera || {};
  $('camera-state').textContent = `camera ${camera.state || '?'}`;
  if (!frame) return;
  $('frame-sequence').textContent = String(frame.frame.sequence);
  $('frame-age').textContent = `(${number(frame.frame.age_ms / 1000, 1)} s old)`;
  const found = frame.detections.map((d) => {
    const at = d.pose ? ` at ${number(d.pose.distance_m, 3)} m` : '';
    return `${d.family} ${d.id}${at}`;
  });
  $('detections').textContent = found.length ? found.join('; ') : 'no marker';
  const p = state.pipeline || {};
  $('pipeline').textContent = `${p.detected} detected, ${p.dropped} dropped (${p.policy})`;
}

function showSweep(state) {
  const sweep = state.sweep;
  if (!sweep) {
    $('sweep-text').textContent = 'no sweeps without a rig';
    return;
  }
  $('sweep-progress').max = Math.max(1, sweep.steps_total);
  $('sweep-progress').value = sweep.steps_done;
  if (sweep.state === 'idle') {
    $('sweep-text').textContent = 'no run since markerd started';
    return;
  }
  let text = `${sweep.run_id}: ${sweep.state}, step ${sweep.steps_done} of ${sweep.steps_total}`;
  if (sweep.step) {
    text += ` \u00b7 ${number(sweep.step.distance_m, 2)} m, ${number(sweep.step.angle_deg, 1)} deg`;
  }
  if (sweep.phase) text += ` \u00b7 ${sweep.phase}`;
  if (typeof sweep.last_rate === 'number') text += ` \u00b7 last rate ${number(100 * sweep.last_rate, 0)}%`;
  if (typeof sweep.remaining_s === 'number') text += ` \u00b7 ${Math.round(sweep.remaining_s)} s left`;
  if (sweep.reason) text += ` \u00b7 ${sweep.reason}`;
  $('sweep-text').textContent = text;
}

async function showReport(runId) {
  if (runId === reportRun) return;
  reportRun = runId;
  $('report-run').textContent = runId ? `run ${runId}` : 'none yet';
  $('report-plots').replaceChildren();
  $('report-files').replaceChildren();
  $('report-text').textContent = '';
  if (!runId) return;
  const index = await (await fetch('/report/index.json')).json();
  for (const name of index.files) {
    const item = document.createElement('li');
    const link = document.createElement('a');
    link.href = '/report/' + encodeURIComponent(name);
    link.textContent = name;
    item.append(link);
    $('report-files').append(item);
    if (name.endsWith('.svg')) {
      const plot = document.createElement('img');
      plot.src = link.href;
      plot.alt = name;
      $('report-plots').append(plot);
    }
  }
  if (index.files.includes('report.md')) {
    $('report-text').textContent = await (await fetch('/report/report.md')).text();
  }
}

async function poll() {
  try {
    const response = await fetch('/state.json', {cache: 'no-store'});
    const state = await response.json();
    $('connection').textContent = 'live';
    $('connection').className = 'good';
    $('status-line').textContent = state.status || '';
    showRig(state);
    showFrame(state);
    showSweep(state);
    await showReport(state.report ? state.report.run_id : null);
    $('updates').textContent = String(++updates);
  } catch (error) {
    $('connection').textContent = 'markerd does not answer';
    $('connection').className = 'bad';
  }
  setTimeout(poll, 500);
}

// A preview that ended (markerd restarted, the limit of previews reached)
// is asked for again after a pause.
$('preview').addEventListener('error', () => {
  setTimeout(() => { $('preview').src = '/preview.mjpg?t=' + Date.now(); }, 2000);
});

poll();
