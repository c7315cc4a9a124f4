/* The inspector's viewer of a stitched facade map (companion/viewer/page.py writes it beside the map).

   Data: window.COMPANION_VIEWER (viewer/data.js; a script, because pages opened from file:// may not fetch).
   Coordinates are wall metres: lng = metres along the wall from its start, lat = metres above its base (or map
   pixels, y up, when the map's scale is unknown). A Leaflet CRS maps them onto the tile pyramid, so Leaflet's
   own distance between two points is a distance on the wall. */
(function () {
  'use strict';
  var D = window.COMPANION_VIEWER;
  var F = D.frame;
  var Z = D.tiles.max_zoom;
  var metres = F.units === 'm';
  var api = { data: D, tilesLoaded: false };
  window.companionViewer = api;

  // level-Z pixel = (along - left) / unit_per_px; Leaflet scales level z by 2^z
  var k = 1 / (F.unit_per_px * Math.pow(2, Z));
  var crs = L.extend({}, L.CRS.Simple, {
    transformation: new L.Transformation(k, -k * F.left, -k, k * F.top)
  });
  var right = F.left + F.width_px * F.unit_per_px;
  var bottom = F.top - F.height_px * F.unit_per_px;
  var bounds = L.latLngBounds([bottom, F.left], [F.top, right]);

  var map = L.map('map', {
    crs: crs, minZoom: 0, maxZoom: Z + 3, zoomSnap: 1, attributionControl: false
  });
  api.map = map;
  api.bounds = bounds;
  var tiles = L.tileLayer(D.tiles.url, {
    tileSize: D.tiles.size, minZoom: 0, maxZoom: Z + 3, minNativeZoom: 0, maxNativeZoom: Z,
    bounds: bounds, noWrap: true
  });
  tiles.on('loading', function () { api.tilesLoaded = false; });
  tiles.on('load', function () { api.tilesLoaded = true; });
  tiles.addTo(map);

  function fmtLength(u) {
    if (!metres) { return u.toFixed(1) + ' px'; }
    var mm = u * 1000;
    return (mm < 100 ? mm.toFixed(1) : mm.toFixed(0)) + ' mm';
  }
  function fmtPos(ll) {
    if (!metres) { return 'x ' + (ll.lng - F.left).toFixed(1) + ' px, y ' + (F.top - ll.lat).toFixed(1) + ' px'; }
    return 'along ' + ll.lng.toFixed(3) + ' m, up ' + ll.lat.toFixed(3) + ' m';
  }
  function el(tag, cls, parent, text) {
    var e = L.DomUtil.create(tag, cls || '', parent);
    if (text !== undefined) { e.textContent = text; }
    return e;
  }

  function fmtArea(a) {  // a re-fly area: wall metres, or map pixels when the scale is unknown
    var r = a.rect;
    if (metres) {
      return 'along ' + r[0].toFixed(2) + '..' + r[1].toFixed(2) + ' m, up ' + r[2].toFixed(2) + '..' +
        r[3].toFixed(2) + ' m, ' + a.area_m2.toFixed(2) + ' m\u00b2';
    }
    return 'x ' + r[0].toFixed(0) + '..' + r[1].toFixed(0) + ' px, y ' + (-r[3]).toFixed(0) + '..' +
      (-r[2]).toFixed(0) + ' px';
  }

  // --- overlays: uncovered wall, re-fly areas, keyframe footprints -------------------------------------------
  var coverage = L.imageOverlay(D.coverage.overlay, bounds, { interactive: false });
  var refly = L.layerGroup(D.refly.map(function (a) {
    var r = a.rect;
    return L.rectangle([[r[2], r[0]], [r[3], r[1]]], { color: '#e33', weight: 2, fillOpacity: 0.08 })
      .bindTooltip('re-fly: ' + fmtArea(a), { sticky: true });
  }));
  // relief: wall the keyframes showed but did not keep as the wall plane (a portal, a recess, glass); no re-fly fills it
  var relief = L.layerGroup((D.relief || []).map(function (a) {
    var r = a.rect;
    return L.rectangle([[r[2], r[0]], [r[3], r[1]]], { color: '#09f', weight: 2, dashArray: '4 3', fillOpacity: 0.05 })
      .bindTooltip('relief (seen, not the flat wall): ' + fmtArea(a), { sticky: true });
  }));
  var footprints = L.layerGroup();
  D.keyframes.forEach(function (kf) {
    kf.latlngs = kf.corners.map(function (c) { return [c[1], c[0]]; });
    kf.centre = kf.corners.reduce(function (s, c) { return [s[0] + c[0] / 4, s[1] + c[1] / 4]; }, [0, 0]);
    footprints.addLayer(L.polygon(kf.latlngs, { color: '#39f', weight: 1, opacity: 0.55, fill: false, interactive: false }));
  });
  coverage.addTo(map);
  refly.addTo(map);
  relief.addTo(map);
  if (D.keyframes.length <= 30) { footprints.addTo(map); }  // hundreds of outlines hide the wall: off, clicks still work
  var overlays = { 'uncovered wall (red tint)': coverage, 're-fly areas': refly, 'relief (blue)': relief,
    'keyframe footprints': footprints };
  L.control.layers(null, overlays, { collapsed: false, position: 'topright' }).addTo(map);
  if (metres) { L.control.scale({ imperial: false, maxWidth: 200 }).addTo(map); }

  // --- which keyframes show a point: the photo whose centre is nearest first -----------------------------------
  function inside(p, poly) {
    var hit = false;
    for (var i = 0, j = poly.length - 1; i < poly.length; j = i++) {
      var a = poly[i], b = poly[j];
      if ((a[1] > p[1]) !== (b[1] > p[1]) && p[0] < (b[0] - a[0]) * (p[1] - a[1]) / (b[1] - a[1]) + a[0]) { hit = !hit; }
    }
    return hit;
  }
  function keyframesAt(ll) {
    var p = [ll.lng, ll.lat];
    return D.keyframes.filter(function (kf) { return inside(p, kf.corners); })
      .sort(function (a, b) {
        return Math.hypot(a.centre[0] - p[0], a.centre[1] - p[1]) - Math.hypot(b.centre[0] - p[0], b.centre[1] - p[1]);
      });
  }
  var chosen = L.polygon([], { color: '#ff0', weight: 3, fill: false, interactive: false });
  function openKeyframe(hits, i, ll) {
    var kf = hits[i];
    chosen.setLatLngs(kf.latlngs).addTo(map);
    var box = el('div', 'kf-popup');
    box.dataset.keyframe = kf.index;
    el('div', 'kf-title', box, 'keyframe ' + kf.index + '  (' + (i + 1) + ' of ' + hits.length + ' showing this point)');
    var popup = L.popup({ maxWidth: 540, minWidth: 300, autoPanPadding: [20, 20] });
    if (kf.image) {
      var a = el('a', '', box);
      a.href = kf.image;
      a.target = '_blank';
      a.title = 'open the original image';
      var img = el('img', 'kf-image', a);
      img.alt = 'keyframe ' + kf.index;
      img.onload = function () { popup.update(); };
      img.src = kf.image;
      el('div', 'kf-note', box, kf.image.split('/').pop() + ' (click for full size)');
    } else {
      el('div', 'kf-note', box, 'image not in this folder: run `companion view DIR --spool SPOOL --rebuild`');
    }
    if (hits.length > 1) {
      var nav = el('div', 'kf-nav', box);
      [['\u2190 previous', hits.length - 1], ['next \u2192', 1]].forEach(function (b) {
        var btn = el('button', '', nav, b[0]);
        L.DomEvent.on(btn, 'click', function (ev) {
          L.DomEvent.stop(ev);
          openKeyframe(hits, (i + b[1]) % hits.length, ll);
        });
      });
    }
    popup.setLatLng(ll).setContent(box).openOn(map);
  }
  map.on('popupclose', function () { chosen.remove(); });

  // --- measuring: click points, read each segment and the total in millimetres -------------------------------
  var measuring = false;
  var pts = [];
  var line = L.polyline([], { color: '#ff0', weight: 2, interactive: false });
  var marks = L.layerGroup();
  var readout = L.control({ position: 'bottomleft' });
  readout.onAdd = function () {
    var box = el('div', 'viewer-panel measure-readout');
    box.id = 'measure-readout';
    box.style.display = 'none';
    return box;
  };
  readout.addTo(map);
  function total() {
    var s = 0;
    for (var i = 1; i < pts.length; i++) { s += map.distance(pts[i - 1], pts[i]); }
    return s;
  }
  function showReadout() {
    var box = readout.getContainer();
    box.style.display = measuring || pts.length > 1 ? '' : 'none';
    box.textContent = '';
    if (pts.length < 2) { el('div', '', box, 'click points on the map to measure (Esc ends)'); return; }
    el('div', '', box, 'last segment: ' + fmtLength(map.distance(pts[pts.length - 2], pts[pts.length - 1])));
    var t = el('div', 'measure-total', box, 'total: ' + fmtLength(total()));
    t.id = 'measure-total';
  }
  function addPoint(ll) {
    pts.push(ll);
    line.setLatLngs(pts);
    marks.addLayer(L.circleMarker(ll, { radius: 4, color: '#ff0', weight: 2, interactive: false }));
    if (pts.length > 1) {
      var a = pts[pts.length - 2];
      var mid = L.latLng((a.lat + ll.lat) / 2, (a.lng + ll.lng) / 2);
      marks.addLayer(L.circleMarker(mid, { radius: 0, opacity: 0, interactive: false })
        .bindTooltip(fmtLength(map.distance(a, ll)), { permanent: true, direction: 'top', className: 'measure-label' }));
    }
    showReadout();
  }
  function startMeasuring() {
    measuring = true;
    pts = [];
    line.setLatLngs(pts).addTo(map);
    marks.clearLayers().addTo(map);
    map.closePopup();
    map.doubleClickZoom.disable();
    L.DomUtil.addClass(map.getContainer(), 'measuring');
    L.DomUtil.addClass(measureButton, 'active');
    showReadout();
  }
  function stopMeasuring() {
    measuring = false;
    map.doubleClickZoom.enable();
    L.DomUtil.removeClass(map.getContainer(), 'measuring');
    L.DomUtil.removeClass(measureButton, 'active');
    showReadout();
  }
  var measureButton;
  var Measure = L.Control.extend({
    options: { position: 'topleft' },
    onAdd: function () {
      var box = el('div', 'leaflet-bar measure-control');
      measureButton = el('a', 'measure-button', box, 'measure');
      measureButton.id = 'measure-button';
      measureButton.href = '#';
      measureButton.title = 'measure distances on the wall: click points, Esc or this button ends';
      L.DomEvent.disableClickPropagation(box);
      L.DomEvent.on(measureButton, 'click', function (ev) {
        L.DomEvent.preventDefault(ev);
        if (measuring) { stopMeasuring(); } else { startMeasuring(); }
      });
      return box;
    }
  });
  new Measure().addTo(map);
  L.DomEvent.on(document, 'keydown', function (ev) { if (ev.key === 'Escape' && measuring) { stopMeasuring(); } });
  api.measure = { start: startMeasuring, stop: stopMeasuring, points: function () { return pts.slice(); }, total: total };

  map.on('click', function (e) {
    if (measuring) { addPoint(e.latlng); return; }
    var hits = keyframesAt(e.latlng);
    if (hits.length) { openKeyframe(hits, 0, e.latlng); } else { map.closePopup(); }
  });

  // --- cursor position and the map's facts -------------------------------------------------------------------
  var pos = L.control({ position: 'bottomright' });
  pos.onAdd = function () {
    var b = el('div', 'viewer-panel', undefined, metres ? 'wall metres under the cursor' : 'map pixels under the cursor');
    b.id = 'cursor-position';
    return b;
  };
  pos.addTo(map);
  map.on('mousemove', function (e) { pos.getContainer().textContent = fmtPos(e.latlng); });

  var info = L.control({ position: 'topright' });
  info.onAdd = function () {
    var panel = el('div', 'viewer-panel viewer-info');
    var box = el('details', '', panel);  // a click on the title folds the panel away from the map
    box.open = true;
    el('summary', 'viewer-title', box, D.title);
    var facts = [];
    if (D.mm_per_px) { facts.push(D.mm_per_px.toFixed(2) + ' mm/px, ' + F.width_px + ' x ' + F.height_px + ' px'); }
    else { facts.push('scale unknown' + (D.scale_note ? ' (' + D.scale_note + ')' : '') + ': lengths in map pixels'); }
    if (D.coverage.fraction !== null && D.coverage.fraction !== undefined) {
      facts.push('coverage ' + (100 * D.coverage.fraction).toFixed(1) + ' %, ' + D.refly.length + ' re-fly area(s)' +
        ((D.relief || []).length ? ', ' + D.relief.length + ' relief area(s)' : ''));
    }
    facts.push(D.keyframes.length ? D.keyframes.length + ' keyframe footprints: click the map to see the photos of a point'
      : 'no keyframe footprints (they need telemetry poses on the mission\'s wall)');
    facts.forEach(function (f) { el('div', '', box, f); });
    if (D.refly.length) {
      var list = el('ol', 'refly-list', box);
      D.refly.slice(0, 12).forEach(function (a) {
        var r = a.rect;
        var item = el('li', '', list);
        var link = el('a', '', item, fmtArea(a));
        link.href = '#';
        L.DomEvent.on(link, 'click', function (ev) {
          L.DomEvent.preventDefault(ev);
          map.fitBounds([[r[2], r[0]], [r[3], r[1]]], { maxZoom: Z, padding: [40, 40] });
        });
      });
    }
    L.DomEvent.disableClickPropagation(panel);
    L.DomEvent.disableScrollPropagation(panel);
    return panel;
  };
  info.addTo(map);

  // The whole wall in view beside the info panel, not under it (its right end and re-fly areas were hidden); in a
  // narrow window the panel may cover up to half the width, and it folds away with a click on its title.
  var panelWidth = info.getContainer().offsetWidth;
  var pad = Math.min(panelWidth + 20, map.getSize().x / 2);
  map.fitBounds(bounds, { paddingTopLeft: [10, 10], paddingBottomRight: [pad, 10] });  // Leaflet's two corners
  api.fitPaddingPx = pad;
})();
